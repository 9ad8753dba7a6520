"""Orchestrators that trade a nominal goal off against learned constraints.

Greedy, weighted-average and MDFT orchestrators, rollouts, the paper's
experiments and the ``mdft`` command line. Uses :mod:`mdft` and :mod:`irl`
through their public APIs only.
"""

from mdft import __version__  # one version for the whole pymdft distribution
