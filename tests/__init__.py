"""The tests: a package, so that they import tests.helpers under --import-mode=importlib."""
