"""Evaluation: retrieval measures of labelled collections."""
