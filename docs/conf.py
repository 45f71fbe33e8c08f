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
# `bpy` exists only as a CPython 3.11 wheel of several hundred MB (extra `gaffer-data[render]`); the
# docs build does not install it, so the few modules that import it at the top are read with a stand-in.
autodoc_mock_imports = ["bpy", "mathutils"]
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
    # Types of numpy, torch, the standard library and the other third-party libraries in our signatures:
    # resolved only through intersphinx (or not at all: jaxtyping, diffusers and transformers publish no
    # inventory that covers their internal module paths).
    (
        r"py:(class|obj|data|func|meth|attr|exc)",
        r"(numpy|np|torch|os|collections\.abc|pathlib|argparse|typing|PIL|logging|jaxtyping|diffusers"
        r"|transformers|safetensors|accelerate|tqdm|concurrent\.futures|subprocess|types|datetime)\..+",
    ),
    # `from torch import Tensor` annotations render as the bare name.
    (r"py:class", r"Tensor|ndarray"),
    # jaxtyping shape strings (`Float[Tensor, "B 3 H W"]`): autodoc splits them into would-be class
    # names at the spaces; every piece carries a quote.
    (r"py:class", r".*'.*"),
]
nitpick_ignore = [
    # A private record type in the signature of a public dataset method (reported upstream).
    ("py:class", "gaffer_diffusion.training.dataset._ViewEntry"),
    (
        "py:class",
        "gaffer_envmap.atomic.T",
    ),  # a TypeVar: autodoc links it, but it has no page of its own
    # The structural view of `gaffer_diffusion.pipelines.RuntimeConfig` that runtime_dtype reads (a
    # Protocol, so that the pipelines are not imported back); users meet only the dataclass.
    ("py:class", "gaffer_diffusion.runtime_dtype.RuntimeConfig"),
]

# The `>>>` examples of the API docstrings run under pytest (`--doctest-modules`, in the module's own
# namespace); the tutorial page's code runs at every build (docs/_scripts/make_figures.py).


def _generate(app) -> None:
    make_figures = importlib.import_module("make_figures")
    make_figures.main(out=DOCS / "_generated", quiet=True)


def _python_domain_preferring_own_package():
    """The Python domain, but an ambiguous short name resolves inside the referring package first.

    Every package has its own `errors.py` (`ConfigError`, `ShapeError`, `MissingDependencyError`, ...),
    so the name `ConfigError` in a `Raises:` section of `gaffer_nerf.configs` matches one class per
    package. The reference means its own package's class; only a name still ambiguous after that is an
    error (Sphinx's warning). A bare name that matches nothing exactly (a type hint autodoc could not
    qualify) is looked up inside the referring package the same way.
    """
    from sphinx.domains.python import PythonDomain

    class GafferPythonDomain(PythonDomain):
        def find_obj(self, env, modname, classname, name, type, searchmode=0):
            matches = super().find_obj(env, modname, classname, name, type, searchmode)
            if not matches and modname and searchmode == 0 and "." not in name:
                # A bare class name from a type hint that autodoc could not qualify: look for it
                # anywhere in the referring package.
                package = modname.split(".")[0] + "."
                fuzzy = super().find_obj(env, modname, classname, name, type, 1)
                matches = [m for m in fuzzy if m[0].startswith(package)]
            if len(matches) > 1 and modname:
                package = modname.split(".")[0] + "."
                own = [m for m in matches if m[0].startswith(package)]
                if own:
                    matches = own
            return matches

    return GafferPythonDomain


def setup(app) -> dict[str, object]:
    app.add_domain(_python_domain_preferring_own_package(), override=True)
    app.connect("builder-inited", _generate)
    # Before napoleon (priority 500): read the Markdown-flavoured docstrings as reST (see the module).
    docstring_compat = importlib.import_module("docstring_compat")
    app.connect("autodoc-process-docstring", docstring_compat.process_docstring, priority=400)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
