"""Sphinx configuration of the pymdft documentation site.

Build it from the repository root with::

    python -m sphinx -W --keep-going -b html docs docs/_build/html

The pages are the Markdown files of ``docs/`` (read by MyST). The API reference is
generated at build time from the ``__all__`` of each package (``docs/_ext/pymdft_docs.py``),
so a new public name appears on the site without an edit here.
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))  # document this checkout, installed or not
sys.path.insert(0, str(DOCS / "_ext"))

project = "pymdft"
author = "the pymdft authors"
copyright = "pymdft authors, MIT licence"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "pymdft_docs",
]

# Pages: Markdown only. The generated API pages are reStructuredText.
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "**/.ipynb_checkpoints"]
templates_path = ["_templates"]

# MyST: $...$ and $$...$$ math, amsmath environments, anchors for links such as
# concepts.md#decisions (GitHub-style slugs, so the same links work on GitHub).
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 4
myst_dmath_double_inline = True

# Autodoc and numpydoc: signatures with their type hints, members listed by
# autodoc (numpydoc's own member tables are off, they would need stub pages).
autodoc_typehints = "signature"
# Show the aliases of mdft._typing and irl._typing by name, not expanded.
autodoc_type_aliases = {name: name for name in ("ArrayLike", "SeedLike", "PathLike")}
autodoc_member_order = "bysource"
autodoc_default_options = {"member-order": "bysource"}
autosummary_generate = False  # the stub pages come from pymdft_docs
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = True

# The pymdft_docs extension: which packages form the API reference.
pymdft_api_packages = ["mdft", "irl", "orchestration"]

# A toctree glob that may match nothing yet: the section appears with its first page.
# Any other empty glob is still an error.
pymdft_optional_globs = ["experiments/*", "orchestration*"]

html_theme = "furo"
html_title = "pymdft"
html_static_path = []
