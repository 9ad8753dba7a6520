"""The ``mdft`` command line.

Commands::

    mdft simulate    simulate an MDFT model given inline or in a JSON file
    mdft effects     the similarity, attraction and compromise effects: table and figure
    mdft reproduce   the paper's experiments: tables, figures and results files
    mdft tour        the whole story in about a minute: tables, figures, an HTML report
    mdft warmup      compile the kernels now, so that no later command pauses to compile

One module per command group (:mod:`.engine` for ``simulate`` and ``effects``,
:mod:`.reproduce`), each a thin layer over library functions; :mod:`._core`
holds the registry, the parser and the error handling. Every user error is
one line on stderr and exit code 2, without a traceback.
"""

from ._core import UsageError, arg, build_parser, main, subcommand, version
from . import engine, reproduce, tour, warmup  # noqa: F401  (registers the commands)

__all__ = ["UsageError", "arg", "build_parser", "main", "subcommand", "version"]
