"""Descriptors: a vector per mesh whose L1 distance compares shapes."""
