"""Built-in plugins of rigslim, one package per stage.

Each package is registered through the ``rigslim`` entry-point group in
``pyproject.toml``, exactly as a third-party plugin package would be.
"""
