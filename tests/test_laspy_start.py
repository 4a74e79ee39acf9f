"""stream.engine.laspy_start and import_hooks: the console script and its workers import laspy without requests."""

import subprocess
import sys
import textwrap

import pytest

RUN = textwrap.dedent("""
    import sys
    from patchcloud.stream.engine.laspy_start import skip_laspy_http
    first = skip_laspy_http()
    import laspy
    import laspy.copc
    skipped = "requests" not in sys.modules and laspy.copc.requests is None
    again = skip_laspy_http()  # laspy imported: too late, says so
    las = laspy.read(sys.argv[1])
    import importlib.util
    if importlib.util.find_spec("requests") is not None:  # another import of it works as before (where it is installed)
        import requests
        later = requests.__name__
    else:
        later = "requests"
    print(first, skipped, again, len(las.points), later)
""")


def test_laspy_imports_without_requests_and_reads_files(tmp_path):
    from test_stream import write_scene

    src = tmp_path / "scene.las"
    write_scene(src, n=2_000, seed=1)
    out = subprocess.run([sys.executable, "-c", RUN, str(src)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True", "False", "2000", "requests"]


def test_the_console_script_and_a_worker_process_skip_requests(tmp_path):
    from test_stream import write_scene

    src = tmp_path / "scene.las"
    write_scene(src, n=2_000, seed=1)
    script = textwrap.dedent(f"""
        import sys
        from patchcloud.stream.cli import run
        import patchcloud.stream.cli as cli
        cli.leave = sys.exit  # (a probe: this process goes on after the command, to look at it)
        sys.argv = ["patchcloud", "info", {str(src)!r}]
        try:
            run()
        except SystemExit:
            pass
        import distributed  # what a local worker has imported when dask calls its set-up
        assert "laspy" not in sys.modules or "requests" not in sys.modules
        print("console", "requests" in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "console False"
    worker = textwrap.dedent("""
        import sys
        import distributed  # noqa: F401  what a worker process has imported before its preload
        from patchcloud.stream.engine import worker_setup

        class Worker:
            state = None

        worker_setup.dask_setup(Worker())
        import laspy  # noqa: F401  what its first task imports
        print("worker", "requests" in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", worker], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "worker False"


SAMPLE = __import__("pathlib").Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"

RUN_PYPROJ = textwrap.dedent("""
    import sys
    from patchcloud.stream.engine.laspy_start import skip_laspy_pyproj
    first = skip_laspy_pyproj()
    import laspy
    skipped = "pyproj" not in sys.modules
    again = skip_laspy_pyproj()  # laspy imported: too late, says so
    header = laspy.open(sys.argv[1]).header
    epsg = header.parse_crs().to_epsg()  # laspy imports pyproj where it reads a CRS, as before
    from patchcloud.stream.io.crs import with_crs
    written = with_crs(laspy.LasHeader(point_format=6, version="1.4"), "EPSG:2154").parse_crs().to_epsg()
    print(first, skipped, again, epsg, written, "pyproj" in sys.modules)
""")


def test_laspy_imports_without_pyproj_and_still_reads_and_writes_crss():
    """laspy's import leaves pyproj out; reading the IGN tile's CRS and writing one import it then."""
    out = subprocess.run([sys.executable, "-c", RUN_PYPROJ, str(SAMPLE)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True", "False", "2154", "2154", "True"]


RUN_TEMPLATES = textwrap.dedent("""
    import sys
    from patchcloud.stream.engine.dask_start import skip_dask_templates
    first = skip_dask_templates()
    import distributed  # noqa: F401
    import dask.widgets
    skipped = "jinja2" not in sys.modules
    again = skip_dask_templates()
    try:
        dask.widgets.get_template("client.html.j2")
        drawn = "drawn"
    except ImportError:  # dask's own answer where its diagnostics are not installed
        drawn = "ImportError"
    import importlib.util
    later = __import__("jinja2").__name__ if importlib.util.find_spec("jinja2") else "jinja2"
    print(first, skipped, again, drawn, later)
""")


def test_dask_imports_without_its_html_templates():
    out = subprocess.run([sys.executable, "-c", RUN_TEMPLATES], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True", "False", "ImportError", "jinja2"]


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_forked_workers_and_a_client_without_a_crs_import_neither_pyproj_nor_jinja2(tmp_path):
    """The fork server's imports (the path to every worker's start) and the console script on a file without a CRS
    leave both out; the console script on a file with one imports pyproj to read it (the first time: see
    test_crs_cache.py for the next)."""
    from test_stream import write_scene

    src = tmp_path / "scene.las"
    write_scene(src, n=3_000, seed=2)  # no CRS
    code = textwrap.dedent(f"""
        import sys
        from patchcloud.stream.engine.runner import Runner
        if __name__ == "__main__":
            with Runner("processes", 1, quiet=True) as r:
                worker = list(r.client.run(lambda: ("pyproj" in sys.modules, "jinja2" in sys.modules)).values())
            print(worker[0][0], worker[0][1])
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.split() == ["False", "False"]
    for path, crs in ((src, "False"), (SAMPLE, "True")):
        console = textwrap.dedent(f"""
            import sys
            if __name__ == "__main__":
                from patchcloud.stream.console import run
                import patchcloud.stream.cli as cli
                cli.leave = sys.exit  # (a probe: this process goes on after the command, to look at it)
                sys.argv = ["patchcloud", "normals", {str(path)!r}, {str(tmp_path / "out.laz")!r}, "-q", "--overwrite",
                            "--workers", "1", "--scheduler", "processes"]
                try:
                    run()
                except SystemExit as e:
                    assert not e.code, e.code
                print("pyproj" in sys.modules, "jinja2" in sys.modules)
        """)
        env = dict(__import__("os").environ, PATCHCLOUD_CRS_CACHE=str(tmp_path / f"crs-{crs}"))  # pyproj's answers not kept yet
        out = subprocess.run([sys.executable, "-c", console], capture_output=True, text=True, timeout=300, env=env)
        assert out.returncode == 0, out.stderr[-3000:]
        assert out.stdout.split()[-2:] == [crs, "False"], path
