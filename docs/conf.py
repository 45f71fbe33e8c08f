"""Sphinx configuration of the gaffer documentation site (furo + myst-parser + autodoc + napoleon).

Build (as `nox -s docs` does): `sphinx-build -n -T -W --keep-going -b html docs docs/_build/html`.

Every figure, the conventions table, the API page list and the benchmark tables are generated from code
at build time by `docs/_scripts/make_figures.py` (called from `builder-inited` below) into
`docs/_generated/` (git-ignored), so they cannot drift from the code they describe.
"""

import importlib
import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_scripts"))

import gaffer_envmap  # noqa: E402

project = "gaffer"
author = "the gaffer authors"
copyright = "2026, the gaffer authors"
release = gaffer_envmap.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
# `_generated/*.md` are fragments pulled into pages with `{include}`, not pages of their own
# (`_generated/api/*.md` are pages).
exclude_patterns = ["_build", "_scripts", "_generated/*.md", "Thumbs.db", ".DS_Store"]
templates_path: list[str] = []
html_theme = "furo"
html_title = f"gaffer {release}"
html_static_path: list[str] = []

myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
myst_heading_anchors = 3

# --- API (autodoc + napoleon, Google style) --------------------------------------------------------
autodoc_default_options = {
    "members": True,
    "undoc-members": False,
    "show-inheritance": True,
    "member-order": "bysource",
}
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autodoc_preserve_defaults = True
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
# Dataclass fields listed under "Attributes:" would otherwise be described twice (napoleon + autodoc).
napoleon_use_ivar = True

# --- Cross-references ------------------------------------------------------------------------------
# intersphinx (torch, numpy, Python) needs the network to fetch the inventories; our CI machines and
# dev boxes have none beyond PyPI, and a failed fetch is a warning that `-W` turns into an error. It is
# therefore opt-in: GAFFER_DOCS_INTERSPHINX=1. Without it, references into those projects are listed
# below as known-external so that `-n` (nitpicky) still reports every broken reference to our own code.
if os.environ.get("GAFFER_DOCS_INTERSPHINX") == "1":
    extensions.append("sphinx.ext.intersphinx")
    intersphinx_mapping = {
        "python": ("https://docs.python.org/3", None),
        "numpy": ("https://numpy.org/doc/stable/", None),
        "torch": ("https://pytorch.org/docs/stable/", None),
    }

nitpick_ignore_regex = [
    # Types of numpy, torch and the standard library: resolved only through intersphinx.
    (
        r"py:(class|obj|data|func|meth|attr|exc)",
        r"(numpy|torch|os|collections\.abc|pathlib|argparse|typing|PIL|logging)\..+",
    ),
]
nitpick_ignore = [
    (
        "py:class",
        "gaffer_envmap.atomic.T",
    ),  # a TypeVar: autodoc links it, but it has no page of its own
]

# The `>>>` examples of the API docstrings run under pytest (`--doctest-modules`, in the module's own
# namespace); the tutorial page's code runs at every build (docs/_scripts/make_figures.py).


def _generate(app) -> None:
    make_figures = importlib.import_module("make_figures")
    make_figures.main(out=DOCS / "_generated", quiet=True)


def setup(app) -> dict[str, object]:
    app.connect("builder-inited", _generate)
    # Before napoleon (priority 500): read the Markdown-flavoured docstrings as reST (see the module).
    docstring_compat = importlib.import_module("docstring_compat")
    app.connect("autodoc-process-docstring", docstring_compat.process_docstring, priority=400)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
