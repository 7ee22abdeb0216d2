"""Test data for the diagnosis, not part of the model: generators of recording sets
with a known hidden effect (:mod:`.concealed`), for the tests, the benchmarks and
``scripts/make_concealed_fixtures.py``. Nothing in the library imports this package.
"""
