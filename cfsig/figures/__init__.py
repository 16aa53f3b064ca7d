"""Figures: meshes drawn coloured, histograms, precision/recall curves, reports."""
