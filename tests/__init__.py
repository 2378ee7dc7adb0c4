"""The test suite, one package (imported as ``tests.*``, the repository root on sys.path).

Test modules sit in folders that mirror the packages they test: ``tests/radical_rt/<package>/``,
``tests/replayer/`` (``synth/`` for the simulator), ``tests/monitors/``, ``tests/perf/``,
``tests/mission/``, ``tests/studies/``; cross-cutting ones (golden outputs, architecture rules,
end to end over Zenoh) in ``tests/system/``. Shared helpers are in ``tests.support``, test
oracles in ``tests.oracles``, frozen records in ``tests/golden``, node readers in ``tests/js``.
"""
