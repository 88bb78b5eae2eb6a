"""Data shipped with AMRST Studio: parameter presets, the sample pair, the app icon.

In a checkout this is the ``resources/`` folder beside the packages; a wheel installs it
as the package ``amrst_resources`` (see ``[tool.setuptools]`` in pyproject.toml).
``amrst.resources.resource_path`` finds it either way.
"""
