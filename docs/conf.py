"""Sphinx configuration of the torchrl_surprise documentation.

Build with ``make docs`` or
``python -m sphinx -W --keep-going -b html docs docs/_build/html``.
No network access is needed: the built-in alabaster theme, and the intersphinx
inventories (PyTorch, TorchRL, TensorDict, NumPy, Python) only where their sites
can be reached (:func:`_reachable`): online, ``:class:`~torchrl.envs.GymEnv```
links to TorchRL's page; offline it is shown as code, and the build, which treats
warnings as errors, does not fail on an inventory it cannot fetch.
"""

from __future__ import annotations

import importlib
import inspect
import os
import pkgutil
import socket
import sys
from pathlib import Path
from urllib.parse import urlsplit

from sphinx.pycode import ModuleAnalyzer

ROOT = Path(__file__).resolve().parent.parent
# The package is installed in editable mode by `make`; this also covers a plain
# checkout on sys.path.
sys.path.insert(0, str(ROOT))

import torchrl_surprise  # noqa: E402

project = "torchrl_surprise"
author = "torchrl_surprise contributors"
copyright = "torchrl_surprise contributors"
release = torchrl_surprise.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.intersphinx",
    "sphinx.ext.napoleon",
]

# Where the classes the docs name (torchrl.envs.Transform, tensordict.TensorDict,
# torch.nn.Module, ...) are documented.
INVENTORIES = {
    "python": "https://docs.python.org/3/",
    "numpy": "https://numpy.org/doc/stable/",
    "torch": "https://pytorch.org/docs/stable/",
    "tensordict": "https://pytorch.org/tensordict/stable/",
    "torchrl": "https://pytorch.org/rl/stable/",
}


def _reachable(url: str, timeout: float = 3.0) -> bool:
    """Whether ``url``'s host accepts a connection (DOCS_OFFLINE=1: never).

    Intersphinx warns for an inventory it cannot fetch, with no warning type to
    suppress, and ``make docs`` turns warnings into errors: an unreachable
    site's inventory is left out instead, and its names are shown unlinked.
    """
    if os.environ.get("DOCS_OFFLINE") == "1":
        return False
    parts = urlsplit(url)
    try:
        with socket.create_connection((parts.hostname, parts.port or 443), timeout):
            return True
    except OSError:
        return False


intersphinx_mapping = {
    name: (url, None) for name, url in INVENTORIES.items() if _reachable(url)
}
intersphinx_timeout = 10

# Each study's status.rst (written by recipes/results/aggregate.py) is a fragment
# to include, not a page of its own.
exclude_patterns = ["_build", "results/**/status.rst"]
templates_path: list[str] = []

html_theme = "alabaster"
html_static_path: list[str] = []
html_theme_options = {"description": "Bayesian-surprise exploration for TorchRL"}

# autodoc: members in source order, type hints in the description (not the
# signature) so long signatures stay readable.
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented"
autodoc_default_options = {
    "show-inheritance": True,
    # The one private method a subclass author needs to see.
    "private-members": "_compute_bonus",
}
# An override without a docstring of its own (``forward`` of an ``nn.Module``,
# ``set_keys`` of a ``LossModule``) would otherwise show the parent's generic text.
autodoc_inherit_docstrings = False
# The autosummary tables of api.rst link to entries documented on the same page;
# no stub pages are generated into the source tree.
autosummary_generate = False

napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_use_ivar = True

# Submodules whose public names are re-exported by ``torchrl_surprise``.
_SUBPACKAGES = ("modules", "objectives", "transforms", "envs")


def _resolve_top_level_alias(app, env, node, contnode):
    """Links ``torchrl_surprise.Name`` to where ``Name`` is documented.

    The top-level package re-exports classes that api.rst documents once, under
    their subpackage (``torchrl_surprise.transforms.VAESurpriseTransform``).
    Docstrings refer to the short top-level path; this resolves such references
    instead of documenting every class twice.
    """
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    prefix = "torchrl_surprise."
    if not target.startswith(prefix) or "." in target[len(prefix) :]:
        return None
    name = target[len(prefix) :]
    if name not in torchrl_surprise.__all__:
        return None
    domain = env.get_domain("py")
    for sub in _SUBPACKAGES:
        module = importlib.import_module(f"torchrl_surprise.{sub}")
        if name in getattr(module, "__all__", ()):
            node["reftarget"] = f"torchrl_surprise.{sub}.{name}"
            return domain.resolve_xref(
                env,
                node["refdoc"],
                app.builder,
                node["reftype"],
                node["reftarget"],
                node,
                contnode,
            )
    return None


def _reexported_data_doc(name: str, obj: object) -> list[str] | None:
    """The doc comment of a constant that a subpackage re-exports, if any.

    A constant has no ``__doc__`` of its own: its documentation is the ``#:``
    comment or the string literal next to its assignment, which autodoc only
    looks for in the module being documented, not in the submodule that
    defines it (``torchrl_surprise.envs.minigrid`` for
    ``torchrl_surprise.envs.MULTIROOM_N3_S4``). For the same reason
    ``automodule`` skips re-exported constants: api.rst lists them with
    ``autodata``.
    """
    for sub in _SUBPACKAGES:
        package = importlib.import_module(f"torchrl_surprise.{sub}")
        for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
            module = sys.modules.get(info.name)
            if module is None or getattr(module, name, None) is not obj:
                continue
            docs = ModuleAnalyzer.for_module(info.name).find_attr_docs()
            if ("", name) in docs:
                return list(docs[("", name)])
    return None


def _use_reexported_data_doc(app, what, name, obj, options, lines):
    """Replaces the docstring of ``str``/``dict``/... by the constant's own."""
    if what == "data":
        doc = _reexported_data_doc(name.rpartition(".")[2], obj)
        if doc is not None:
            lines[:] = doc


def _init_signature(app, what, name, obj, options, signature, return_annotation):
    """Shows ``__init__``'s parameters for classes with a generic ``__new__``.

    TorchRL's ``LossModule`` defines ``__new__(cls, *args, **kwargs)``, which
    autodoc would otherwise display as the signature of every loss.
    """
    if what != "class" or signature != "(*args, **kwargs)":
        return None
    try:
        init = inspect.signature(obj.__init__)
    except (TypeError, ValueError):
        return None
    params = [
        p.replace(annotation=inspect.Parameter.empty)
        for p in list(init.parameters.values())[1:]
    ]
    init = init.replace(parameters=params, return_annotation=inspect.Signature.empty)
    return str(init), return_annotation


def setup(app):
    app.connect("missing-reference", _resolve_top_level_alias)
    app.connect("autodoc-process-signature", _init_signature)
    app.connect("autodoc-process-docstring", _use_reexported_data_doc)
