"""radar_env.common.numba_cache: cached kernels are dropped when a source they depend on changes (numba itself keys a
kernel's cache on its own file only), and kept otherwise."""

from types import SimpleNamespace

from radar_env.filters import kernels
from radar_env.common import numba_cache


def _fake_dispatcher(cache_dir):
    return SimpleNamespace(_cache=SimpleNamespace(_cache_path=str(cache_dir)))


def _cached(cache_dir, *names):
    for n in names:
        (cache_dir / n).write_bytes(b"x")


def test_a_changed_source_drops_the_packages_cached_kernels_only(tmp_path, monkeypatch):
    monkeypatch.setattr(numba_cache, "_checked", set())
    src, cache = tmp_path / "pkg", tmp_path / "pkg" / "__pycache__"
    cache.mkdir(parents=True)
    (src / "kern.py").write_text("A = 1\n")
    (src / "env.py").write_text("B = 2\n")
    sources = numba_cache.package_sources(src)
    mine = ["kern.f-10.py311.nbi", "kern.f-10.py311.1.nbc", "env.g-3.py311.nbi"]
    _cached(cache, *mine, "other.h-1.py311.nbi", "kern.cpython-311.pyc")
    numba_cache.drop_stale_kernels(_fake_dispatcher(cache), sources)        # no stamp yet: unknown provenance
    assert sorted(p.name for p in cache.iterdir()) == sorted(
        ["other.h-1.py311.nbi", "kern.cpython-311.pyc", numba_cache.STAMP_NAME])
    assert (cache / numba_cache.STAMP_NAME).read_text().strip() == numba_cache.sources_digest(sources)

    _cached(cache, *mine)                                                    # recompiled from these sources
    monkeypatch.setattr(numba_cache, "_checked", set())                       # a new process, same sources
    numba_cache.drop_stale_kernels(_fake_dispatcher(cache), sources)
    assert all((cache / n).is_file() for n in mine)

    (src / "env.py").write_text("B = 3\n")                                   # e.g. a constant a kernel reads
    monkeypatch.setattr(numba_cache, "_checked", set())
    numba_cache.drop_stale_kernels(_fake_dispatcher(cache), sources)
    assert not any((cache / n).exists() for n in mine)
    assert (cache / "other.h-1.py311.nbi").is_file()


def test_a_read_only_or_unknown_cache_is_left_alone(tmp_path, monkeypatch):
    monkeypatch.setattr(numba_cache, "_checked", set())
    numba_cache.drop_stale_kernels(object(), [])                              # numba internals changed: no error
    (tmp_path / "m.py").write_text("")
    blocker = tmp_path / "file"
    blocker.write_text("")
    numba_cache.drop_stale_kernels(_fake_dispatcher(blocker / "cache"), [tmp_path / "m.py"])   # cannot create


def test_the_kernels_cache_is_stamped_with_the_current_sources():
    cache = kernels.k_update._cache._cache_path
    stamp = numba_cache.Path(cache) / numba_cache.STAMP_NAME
    sources = numba_cache.package_sources(numba_cache.Path(kernels.__file__).parents[1])   # all of radar_env
    assert stamp.read_text().strip() == numba_cache.sources_digest(sources)
