"""Test data for the diagnosis, not part of the model: generators of recording sets
with a known hidden effect, for the tests, the benchmarks and the fixture scripts.
:mod:`.concealed` (the twelve concealed fixture sets and their variants),
:mod:`.random_sets` (random sets, the development and the frozen test split of issue
#27), :mod:`.effects` (effect components only those use), :mod:`.truth` (the known
truths). Nothing in the library imports this package.
"""
