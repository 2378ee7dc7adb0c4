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
