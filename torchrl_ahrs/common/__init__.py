"""Helpers every layer may use: text capping and a background thread. They import nothing from the package
(the bottom of the import graph)."""
