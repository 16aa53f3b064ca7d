"""Repair: from any triangle input to a surface the descriptors mean something on."""
