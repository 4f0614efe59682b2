"""Sphinx configuration of the API reference, built from the docstrings.

CI: ``python -m sphinx -W --keep-going -b html docs/api docs/api/_build`` (warnings are errors, so a
docstring that no longer matches its signature, or a broken reference, fails the build).
"""

project = "torchrl_ahrs"
extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon"]
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"members": True, "show-inheritance": True}
napoleon_google_docstring = True
napoleon_numpy_docstring = False
nitpicky = False
exclude_patterns = ["_build"]
html_theme = "alabaster"
suppress_warnings = ["ref.python"]  # cross-references into TorchRL/tensordict, which are not built here
