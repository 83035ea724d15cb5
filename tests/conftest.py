"""Hypothesis profiles of the fuzz suite (tests/test_fuzz.py).

"ci" runs with the default suite: few cases, derandomized so a run is reproducible, and under
60 s on 2 cores. "large" runs with ``pytest -m slow``: random cases, at least 10,000 in all.
Each fuzz test scales ``max_examples`` by its own weight. Time and memory are bounded by the
tests themselves (a SIGALRM timer and RLIMIT_DATA), so Hypothesis's deadline is off: it is
flaky on a shared machine and cannot stop a hang anyway.
"""

from hypothesis import HealthCheck, settings

settings.register_profile("ci", max_examples=30, derandomize=True, deadline=None, database=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("large", max_examples=2000, deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
