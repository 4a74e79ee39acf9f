"""stream.engine.numba_start: the console script's numba skips its BLAS probe, and the kernels give the same results."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

RUN = textwrap.dedent("""
    import sys
    import numpy as np
    skip = sys.argv[1] == "skip"
    if skip:
        from patchcloud.stream.engine.numba_start import skip_numba_blas_probe
        assert skip_numba_blas_probe()
    from patchcloud.core import estimate_normals
    xy = np.random.default_rng(0).uniform(0, 10, (20000, 2))
    pts = np.column_stack([xy, 0.3 * np.sin(xy[:, 0]) + 0.1 * xy[:, 1]])
    res = estimate_normals(pts)
    import numba.np.arraymath
    heavy = "scipy.linalg" in sys.modules
    blas = numba.np.arraymath._HAVE_BLAS
    import scipy.linalg.cython_blas  # another import of it works as before
    from patchcloud.stream.engine.numba_start import skip_numba_blas_probe
    again = skip_numba_blas_probe()  # numba has probed already: too late, says so
    sys.stdout.buffer.write(repr((heavy, blas, again)).encode() + b"\\n" + res.normals.tobytes() + res.curvature.tobytes())
""")


def _run(mode):
    out = subprocess.run([sys.executable, "-c", RUN, mode], capture_output=True, timeout=600)
    assert out.returncode == 0, out.stderr.decode()[-2000:]
    head, _, data = out.stdout.partition(b"\n")
    return eval(head.decode()), data


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_the_probe_is_skipped_and_the_kernels_give_the_same_bits():
    (heavy, blas, again), skipped = _run("skip")
    assert (heavy, blas, again) == (False, False, False)  # scipy.linalg not imported by numba; numba found no BLAS
    (heavy, blas, again), plain = _run("plain")
    assert heavy and blas  # without the skip numba imports scipy.linalg and finds its BLAS
    assert len(skipped) == len(plain) > 0 and skipped == plain
    assert np.isfinite(np.frombuffer(plain[: 20000 * 12], dtype=np.float32)).all()


LIGHT = textwrap.dedent("""
    import sys
    # modules numba's refresh imports and no kernel of patchcloud's needs (others, numba.np.arraymath, ..., a cached
    # kernel's environment imports as it loads)
    REFRESH_ONLY = ("numba.np.polynomial.polynomial_functions", "numba.typed.typedset", "numba.cpython.printimpl")
    import numpy as np
    from patchcloud.stream.engine.numba_start import load_cached_kernels_lightly
    if sys.argv[1] == "light":
        assert load_cached_kernels_lightly()
    from patchcloud.core import estimate_normals
    xy = np.random.default_rng(0).uniform(0, 10, (20000, 2))
    pts = np.column_stack([xy, 0.3 * np.sin(xy[:, 0]) + 0.1 * xy[:, 1]])
    res = estimate_normals(pts)
    refreshed = any(m in sys.modules for m in REFRESH_ONLY)
    from numba.core import base
    events = sum("llvm_lock" in getattr(a, "__qualname__", "") for a, _ in base.ll.ffi.lib._lock._cblist)  # numba's callbacks
    sys.path.insert(0, sys.argv[2])
    import kernel_for_light_test as k  # a kernel of its own cache: cached for floats by the first run, ints compiled anew
    once = k.twice(1.5)
    deferred = "_bitcode_for_linking" in k.twice.overloads[k.twice.signatures[0]].library.__dict__  # no bitcode parsed yet
    # quad, not cached, calls twice: compiling it links twice's library loaded from the cache, whose bitcode it needs
    extra = (once, k.twice(3), k.quad(1.5)) if sys.argv[3] == "both" else (once,)
    sys.stdout.buffer.write(repr((refreshed, events, extra, deferred)).encode() + b"\\n" + res.normals.tobytes() + res.curvature.tobytes())
""")


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_cached_kernels_load_without_the_refresh_and_give_the_same_bits(tmp_path):
    (tmp_path / "kernel_for_light_test.py").write_text(
        "import numba\n\n@numba.njit(cache=True)\ndef twice(x):\n    return 2 * x\n\n\n"
        "@numba.njit\ndef quad(x):\n    return twice(twice(x))\n")

    def run(mode, calls):
        out = subprocess.run([sys.executable, "-c", LIGHT, mode, str(tmp_path), calls], capture_output=True, timeout=600)
        assert out.returncode == 0, out.stderr.decode()[-2000:]
        head, _, data = out.stdout.partition(b"\n")
        return eval(head.decode()), data

    (refreshed, events, extra, deferred), plain = run("plain", "floats")  # also fills the caches
    assert refreshed and events == 1 and extra == (3.0,) and not deferred
    (refreshed, events, extra, deferred), light = run("light", "floats")
    assert not refreshed  # every kernel came from the cache, without numba's compiler set-up
    assert events == 0  # nor numba's events on llvmlite's lock
    assert deferred  # nor its bitcode parsed
    assert extra == (3.0,) and light == plain and len(plain) > 0
    (refreshed, events, extra, deferred), light = run("light", "both")  # a signature not in the cache compiles in full
    assert extra == (3.0, 6, 6.0) and light == plain  # and quad links with twice's lazily parsed bitcode


SYMBOLS = textwrap.dedent("""
    import sys
    import numpy as np
    from patchcloud.stream.engine.numba_start import load_cached_kernels_lightly
    if sys.argv[1] == "light":
        assert load_cached_kernels_lightly()
    from patchcloud.core import estimate_normals
    xy = np.random.default_rng(0).uniform(0, 10, (20000, 2))
    estimate_normals(np.column_stack([xy, 0.3 * np.sin(xy[:, 0]) + 0.1 * xy[:, 1]]))
    kernels = {id(d): d for name, m in list(sys.modules.items()) if name.startswith("patchcloud.core")
               for d in vars(m).values() if hasattr(d, "overloads") and hasattr(d, "signatures")}
    libraries = [d.overloads[s].library for d in kernels.values() for s in d.signatures]
    lazy = sum("_bitcode_for_linking" in lib.__dict__ for lib in libraries)
    from numba.core.registry import cpu_target
    print(len(libraries), lazy, sorted(cpu_target.target_context.codegen()._engine._defined_symbols))
""")


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_kernels_loaded_without_their_bitcode_define_the_symbols_numba_reads_from_it():
    """stream.engine.numba_start.defined_symbols: numba's JIT engine knows the same symbols after a run whose kernels'
    names came from their object code (bitcode not parsed) as after one where numba parsed their bitcode."""
    def run(mode):
        out = subprocess.run([sys.executable, "-c", SYMBOLS, mode], capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
        loaded, lazy, names = out.stdout.split(" ", 2)
        return int(loaded), int(lazy), names

    run("plain")  # the first run may compile (and cache) kernels
    loaded, lazy, plain = run("plain")
    assert loaded > 5 and lazy == 0
    loaded, lazy, light = run("light")
    assert lazy == loaded > 5 and light == plain and plain.count("'") > 200


def test_a_module_imported_meanwhile_is_there_once_its_thread_ends_and_a_bad_name_is_left_to_the_caller():
    """stream.engine.import_hooks.import_meanwhile: the client imports numcodecs while the read step runs."""
    code = textwrap.dedent("""
        import sys
        from patchcloud.stream.engine.import_hooks import import_meanwhile
        before = "numcodecs" in sys.modules
        t = import_meanwhile("numcodecs", "no_such_module_here")
        t.join()
        print(before, "numcodecs" in sys.modules, import_meanwhile("numcodecs") is None)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["False", "True", "True"]


YAML = textwrap.dedent("""
    import os, sys
    from patchcloud.stream.engine.numba_start import skip_numba_yaml
    skipped = skip_numba_yaml()
    import numba
    sys.stdout.write(repr((skipped, "yaml" in sys.modules, numba.config.NUMBA_NUM_THREADS)))
""")


def test_numba_imports_yaml_only_for_its_settings_file(tmp_path):
    """Without a .numba_config.yaml in the working directory numba's import leaves PyYAML alone; with one, numba reads
    it as usual (here: its num_threads)."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}

    def run():
        out = subprocess.run([sys.executable, "-c", YAML], capture_output=True, timeout=600, cwd=tmp_path, env=env)
        assert out.returncode == 0, out.stderr.decode()[-2000:]
        return eval(out.stdout.decode())

    skipped, has_yaml, _ = run()
    assert skipped and not has_yaml
    (tmp_path / ".numba_config.yaml").write_text("num_threads: 1\n")
    skipped, has_yaml, threads = run()
    assert not skipped and has_yaml and threads == 1
