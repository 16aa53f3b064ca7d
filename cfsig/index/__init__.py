"""The index: a folder of immutable HDF5 segments behind an atomically replaced manifest."""
