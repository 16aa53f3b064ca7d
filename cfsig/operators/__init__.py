"""Operators: the Laplacian, curvature, the conformal factor and the spectrum of a mesh."""
