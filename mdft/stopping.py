"""Stopping rules of an MDFT deliberation: :class:`FixedTime` and :class:`Threshold`."""

from __future__ import annotations

from dataclasses import dataclass

from ._validation import MAX_STEPS, MAX_THETA, as_count, as_scalar

__all__ = ["FixedTime", "Threshold"]


@dataclass(frozen=True)
class FixedTime:
    """Stop after a fixed number of deliberation steps and choose ``argmax P(n_steps)``.

    Parameters
    ----------
    n_steps : int
        Deliberation time ``T``, at least 1 and at most 10,000,000 (``MAX_STEPS``).

    Examples
    --------
    >>> FixedTime(100)
    FixedTime(n_steps=100)
    """

    n_steps: int

    def __post_init__(self):
        object.__setattr__(self, "n_steps", as_count("n_steps", self.n_steps, high=MAX_STEPS))


@dataclass(frozen=True)
class Threshold:
    """Stop as soon as some preference reaches ``theta``; give up after ``max_steps``.

    Parameters
    ----------
    theta : float
        Preference threshold, > 0 and at most 1e300 (``MAX_THETA``: the preference that
        first passes it is still finite, so the choice is made among numbers).
    max_steps : int, default 10_000
        Longest deliberation, at most 10,000,000 (``MAX_STEPS``). A trial that has not reached the threshold after
        ``max_steps`` steps is *undecided*: it is counted in
        ``SimulationResult.n_undecided``, never dropped.

    Notes
    -----
    The trial stops at the first step ``t >= 1`` with ``max_i P_i(t) >= theta``
    and chooses the option with the largest preference at that step (when
    several options cross in the same step, the one furthest past the
    threshold); exact ties are broken uniformly at random.

    Examples
    --------
    >>> Threshold(17.5)
    Threshold(theta=17.5, max_steps=10000)
    """

    theta: float
    max_steps: int = 10_000

    def __post_init__(self):
        object.__setattr__(self, "theta", as_scalar("theta", self.theta, low=0.0,
                                                    low_inclusive=False, high=MAX_THETA))
        object.__setattr__(self, "max_steps", as_count("max_steps", self.max_steps,
                                                       high=MAX_STEPS))
