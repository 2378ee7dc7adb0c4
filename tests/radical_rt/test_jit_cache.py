"""The stale-cache guard of radical_rt._jit: cached kernels of a directory are dropped as a unit
when a kernel module they may embed changes (Numba alone checks only a kernel's own file)."""

from __future__ import annotations

from radical_rt import _jit


def _fresh(monkeypatch):
    monkeypatch.setattr(_jit, "_checked", set())


def test_cache_dropped_when_a_kernel_module_changes(tmp_path, monkeypatch):
    mod = tmp_path / "kern.py"
    mod.write_text("@kernel\ndef f(x):\n    return x\n")
    (tmp_path / "notes.py").write_text("# no kernels here\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    (cache / "kern.f-1.py311.nbi").write_text("old index")
    (cache / "kern.f-1.py311.1.nbc").write_text("old code")
    (cache / "kern.cpython-311.pyc").write_text("bytecode")

    _fresh(monkeypatch)
    _jit._drop_stale_cache(str(mod))  # no stamp yet: drop everything cached
    assert not list(cache.glob("*.nb*"))
    assert (cache / "kern.cpython-311.pyc").exists()  # only Numba's files are touched
    stamp = (cache / "kernels.stamp").read_text()

    (cache / "kern.f-1.py311.nbi").write_text("fresh index")
    _fresh(monkeypatch)
    _jit._drop_stale_cache(str(mod))  # nothing changed: the cache stays
    assert (cache / "kern.f-1.py311.nbi").exists()

    (tmp_path / "notes.py").write_text("# still no kernels, edited\n")
    _fresh(monkeypatch)
    _jit._drop_stale_cache(str(mod))  # a module without kernels does not count
    assert (cache / "kern.f-1.py311.nbi").exists()

    # a module the kernel module imports (constants frozen into its code) counts
    (tmp_path / "layout.py").write_text("N = 3\n")
    mod.write_text("from pkg import layout as L\n@kernel\ndef f(x):\n    return x + L.N\n")
    _fresh(monkeypatch)
    _jit._drop_stale_cache(str(mod))
    (cache / "kern.f-1.py311.nbi").write_text("fresh index")
    stamp = (cache / "kernels.stamp").read_text()
    (tmp_path / "layout.py").write_text("N = 4\n")
    _fresh(monkeypatch)
    _jit._drop_stale_cache(str(mod))
    assert not (cache / "kern.f-1.py311.nbi").exists()
    assert (cache / "kernels.stamp").read_text() != stamp
    stamp = (cache / "kernels.stamp").read_text()

    mod.write_text("@kernel\ndef f(x):\n    return x + 1\n")
    _fresh(monkeypatch)
    _jit._drop_stale_cache(str(mod))
    assert not (cache / "kern.f-1.py311.nbi").exists()
    assert (cache / "kernels.stamp").read_text() != stamp


def test_policy_is_in_the_fingerprint(tmp_path):
    """The compile policy is part of every kernel: changing it changes the fingerprint."""
    before = _jit._fingerprint(tmp_path)
    policy = dict(_jit._POLICY)
    try:
        _jit._POLICY["fastmath"] = True
        assert _jit._fingerprint(tmp_path) != before
    finally:
        _jit._POLICY.clear()
        _jit._POLICY.update(policy)
    assert _jit._fingerprint(tmp_path) == before


def test_kernels_in_subpackages_are_one_unit(tmp_path, monkeypatch):
    """A kernel in pkg/engine/ that imports a kernel module of pkg/kernels/ (and its layout
    module) is recompiled when either changes; the package's own tree is covered recursively."""
    (tmp_path / "kernels").mkdir()
    (tmp_path / "engine").mkdir()
    ud = tmp_path / "kernels" / "ud.py"
    lay = tmp_path / "kernels" / "lay.py"
    ud.write_text("from . import lay\n@kernel\ndef g(x):\n    return x * lay.N\n")
    lay.write_text("N = 2\n")
    eng = tmp_path / "engine" / "loop.py"
    eng.write_text("from ..kernels.ud import g\n@kernel\ndef f(x):\n    return g(x)\n")
    srcs = _jit._kernel_sources(tmp_path)
    assert {p.relative_to(tmp_path).as_posix() for p in srcs} == {
        "kernels/ud.py", "kernels/lay.py", "engine/loop.py"}
    before = _jit._fingerprint(tmp_path)
    lay.write_text("N = 3\n")
    assert _jit._fingerprint(tmp_path) != before
    # the real package: every kernel module of radical_rt, wherever it lives, is covered
    pkg = {p.name for p in _jit._kernel_sources(_jit._PACKAGE)}
    assert {"loop.py", "steps.py", "propagate.py", "clock_layout.py", "layout.py"} <= pkg
