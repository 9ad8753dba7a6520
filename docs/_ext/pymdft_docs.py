"""Sphinx extension of the pymdft site: the API reference and the command-line reference.

API reference
    At ``builder-inited``, for every package named in the ``pymdft_api_packages``
    setting, the public names of its ``__all__`` (and those of its public
    submodules' ``__all__`` that it does not re-export, such as ``mdft.plot``) are
    grouped by the module that defines them and written to ``api/<package>.rst``
    (summary tables) and ``api/generated/<owner>.<name>.rst`` (one page per object,
    filled by autodoc).
    The API reference therefore follows ``__all__``: a name added there is on the
    site at the next build, and a name removed disappears. The generated files are
    not committed (``docs/.gitignore``); they are rewritten only when they change.

Command line
    The ``mdft-cli`` directive prints the help of the ``mdft`` command and of each
    of its subcommands, taken from ``orchestration.cli.build_parser()`` at build
    time, so the reference cannot drift from the program.

Checked cross-references
    A Python cross-reference written in a page of the guide (``{func}`mdft.simulate```
    in Markdown) that names no documented object is a warning, hence an error under
    ``-W``: the links from the equations to the functions cannot rot silently. The
    generated API pages are not held to this (their type hints name NumPy types).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import os
import pkgutil
import re
from collections import defaultdict
from pathlib import Path

from docutils import nodes
from sphinx.pycode import ModuleAnalyzer
from sphinx.util import logging as sphinx_logging
from sphinx.util.docutils import SphinxDirective

logger = sphinx_logging.getLogger(__name__)

_WIDTH = "88"  # columns of the generated help text, whatever the terminal


# --------------------------------------------------------------------------- API pages
def _defining_module(package: str, name: str, obj) -> str:
    """The submodule of ``package`` where ``name`` is defined.

    Classes and functions know it (``__module__``); a constant is found by the
    top-level assignment ``name = ...`` in the package's own modules.
    """
    module = getattr(obj, "__module__", None)
    if isinstance(module, str) and module.startswith(package) and (
        inspect.isclass(obj) or inspect.isroutine(obj)
    ):
        return module
    pkg = importlib.import_module(package)
    for path in sorted(Path(pkg.__file__).parent.glob("*.py")):
        if path.stem == "__init__":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            targets = (
                node.targets if isinstance(node, ast.Assign)
                else [node.target] if isinstance(node, ast.AnnAssign) else []
            )
            if any(isinstance(t, ast.Name) and t.id == name for t in targets):
                return f"{package}.{path.stem}"
    return package


def _kind(obj) -> str:
    if inspect.isclass(obj):
        return "exception" if issubclass(obj, BaseException) else "class"
    if inspect.isroutine(obj):
        return "function"
    return "data"


def _first_paragraph(doc: str | None) -> str:
    lines = []
    for line in inspect.cleandoc(doc or "").splitlines():
        if not line.strip():
            break
        lines.append(line)
    return " ".join(lines)


def _title(text: str, char: str) -> str:
    return f"{text}\n{char * len(text)}\n"


def _object_page(owner: str, name: str, obj, module: str) -> str:
    """The page of ``owner.name``; ``module`` is where the object is defined."""
    full = f"{owner}.{name}"
    # :orphan: the object pages are reached from the summary tables of the package page,
    # not from the navigation tree, which stays small (and the build fast).
    head = ":orphan:\n\n" + _title(full, "=") + f"\n.. currentmodule:: {owner}\n\n"
    kind = _kind(obj)
    if kind == "class":
        return head + f".. autoclass:: {name}\n   :members:\n   :show-inheritance:\n"
    if kind == "exception":
        return head + f".. autoexception:: {name}\n   :show-inheritance:\n"
    if kind == "function":
        return head + f".. autofunction:: {name}\n"
    # A constant: its documentation is the attribute docstring (or ``#:`` comment)
    # of the module that defines it; autodata would look in the package instead.
    docs = ModuleAnalyzer.for_module(module).find_attr_docs().get(("", name), [])
    text = "\n".join(f"   {line}" if line else "" for line in docs)
    value = repr(obj)
    option = (f"   :value: {value}\n" if len(value) <= 120 and "\n" not in value
              else f"   :type: {type(obj).__module__}.{type(obj).__qualname__}\n")
    return head + f".. data:: {name}\n{option}\n{text}\n"


def public_names(module: str) -> list[str]:
    """``__all__`` of ``module`` (empty when it declares none)."""
    return list(getattr(importlib.import_module(module), "__all__", []))


def public_objects(package: str) -> list[tuple[str, str]]:
    """Every public name of ``package`` as ``(owner, name)``, documented as ``owner.name``.

    The names of the package's ``__all__`` come first (owner: the package), then the
    names that a public submodule (no leading underscore) lists in its ``__all__`` but
    the package does not re-export (owner: the submodule), such as ``mdft.plot``.
    """
    pkg = importlib.import_module(package)
    found = [(package, name) for name in public_names(package)]
    exported = {id(getattr(pkg, name)) for _, name in found}
    for info in pkgutil.iter_modules(getattr(pkg, "__path__", [])):
        if info.name.startswith("_"):
            continue
        module = f"{package}.{info.name}"
        mod = importlib.import_module(module)
        found += [(module, name) for name in public_names(module)
                  if id(getattr(mod, name)) not in exported]
    return found


def _package_page(package: str, groups: dict[str, list[tuple[str, str]]]) -> str:
    out = [f".. _api-{package}:\n", _title(f"``{package}``", "="),
           f".. automodule:: {package}\n   :no-members:\n",
           f".. currentmodule:: {package}\n"]
    if not groups:
        out.append(f"``{package}`` declares no public names in ``__all__``.\n")
    for module, entries in groups.items():
        out.append(_title(f"``{module}``", "-"))
        summary = _first_paragraph(importlib.import_module(module).__doc__)
        if summary and module != package:
            out.append(summary + "\n")
        out.append(".. autosummary::\n   :nosignatures:\n\n"
                   + "".join(f"   ~{owner[len(package) + 1:]}.{name}\n" if owner != package
                             else f"   {name}\n" for owner, name in entries))
    return "\n".join(out)


def _write_if_changed(path: Path, text: str) -> None:
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def generate_api_pages(app) -> None:
    api = Path(app.srcdir) / "api"
    generated = api / "generated"
    written = set()
    for package in app.config.pymdft_api_packages:
        groups: dict[str, list[tuple[str, str]]] = defaultdict(list)
        for owner, name in public_objects(package):
            obj = getattr(importlib.import_module(owner), name)
            module = _defining_module(package, name, obj)
            groups[module].append((owner, name))
            page = generated / f"{owner}.{name}.rst"
            _write_if_changed(page, _object_page(owner, name, obj, module))
            written.add(page)
        _write_if_changed(api / f"{package}.rst", _package_page(package, dict(groups)))
    for stale in generated.glob("*.rst") if generated.exists() else ():
        if stale not in written:
            stale.unlink()


# --------------------------------------------------------------------------- CLI help
def _help_texts() -> list[tuple[str, str]]:
    """(command, help text) for ``mdft`` and each subcommand, in registration order."""
    from orchestration.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = _WIDTH
    try:
        parser = build_parser()
        texts = [("mdft", parser.format_help())]
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    texts.append((f"mdft {name}", sub.format_help()))
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old
    return texts


class CommandLineHelp(SphinxDirective):
    """``mdft-cli``: the ``--help`` of ``mdft`` and of every subcommand."""

    has_content = False

    def run(self):
        result = []
        for command, text in _help_texts():
            ident = nodes.make_id(f"cli {command}")
            target = nodes.target("", "", ids=[ident])
            rubric = nodes.rubric("", "")
            rubric += nodes.literal(command, command)
            block = nodes.literal_block(text, text)
            block["language"] = "text"
            result += [target, rubric, block]
        return result


# --------------------------------------------------------------------------- empty globs
class _OptionalGlobs:
    """Drop the warning about a toctree glob that matches no page yet, for the globs
    named in the ``pymdft_optional_globs`` setting only (e.g. ``experiments/*``: the
    section appears with its first page). Every other empty glob is still an error.
    """

    def __init__(self, app):
        self.app = app

    def filter(self, record) -> bool:
        if "didn't match any documents" not in str(record.msg):
            return True
        return not any(glob in record.getMessage()
                       for glob in map(repr, self.app.config.pymdft_optional_globs))


_ALIAS_REPR = re.compile(r"TypeAliasForwardRef\('(\w+)'\)")


def _alias_names(app, what, name, obj, options, signature, return_annotation):
    """``autodoc-process-signature``: show ``ArrayLike | None``, not the repr of Sphinx's
    placeholder for an alias of ``autodoc_type_aliases`` inside a union."""
    if signature is None and return_annotation is None:
        return None
    fix = (lambda text: text if text is None else _ALIAS_REPR.sub(r"\1", text))
    return fix(signature), fix(return_annotation)


_CHECKED_ROLES = {"func", "class", "meth", "attr", "data", "exc", "mod", "obj"}


def _warn_unresolved(app, env, node, contnode):
    """``missing-reference``: warn about an unresolved Python reference in a guide page."""
    if (node.get("refdomain") == "py" and node.get("reftype") in _CHECKED_ROLES
            and not node.get("refdoc", "").startswith("api/")):
        logger.warning("unresolved reference %r: no such documented object",
                       node.get("reftarget"), location=node)
    return None


def setup(app):
    import logging

    app.add_config_value("pymdft_optional_globs", [], "env")
    logging.getLogger("sphinx.sphinx.directives.other").addFilter(_OptionalGlobs(app))
    app.add_config_value("pymdft_api_packages", [], "env")
    app.connect("builder-inited", generate_api_pages)
    app.add_directive("mdft-cli", CommandLineHelp)
    app.connect("missing-reference", _warn_unresolved)
    app.connect("autodoc-process-signature", _alias_names)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
