"""Shared pieces of the fuzz suites: settings, junk values and the check of what escapes."""

import warnings

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

FUZZ = settings(max_examples=25, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])

huge_ints = st.sampled_from([2**63, -(2**63) - 1, 10**400, -(10**400), 2**64])
odd = st.one_of(
    st.none(), st.booleans(), st.text(max_size=5), huge_ints,
    st.floats(allow_nan=True, allow_infinity=True),
    st.lists(st.integers(-3, 3), max_size=3), st.just({"a": 1}), st.just(object()),
)
scalars = st.one_of(odd, st.floats(-1e300, 1e300), st.integers(-10, 10))


def run(call, *names, errors=(ValueError, TypeError)):
    """Call; an error of ``errors`` must name one of ``names``; nothing else may escape."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with np.errstate(all="ignore"):
            try:
                call()
            except errors as exc:
                message = str(exc)
                assert any(name in message for name in names), (names, message)
                assert len(message) > 20, message
