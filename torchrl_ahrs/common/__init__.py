"""Helpers every layer may use: they import nothing from the package (the bottom of the import graph)."""
