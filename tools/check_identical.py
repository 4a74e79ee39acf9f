"""Fingerprints of the jobs' outputs, to show a change leaves them byte-identical.

    python tools/check_identical.py --out after.json [--city-points 1000000] [--workdir DIR] [--compare before.json]

Runs ``patchcloud normals``, ``don --mode exact``, ``segment`` and
``compress`` through the command line (so any version of the package can
be fingerprinted the same way) on the embedded IGN sample and on a
synthetic city (``tools/city_las.py``, seed 0), and writes one SHA-256 per
output file:

- LAS/LAZ outputs: the whole file;
- ``.pcz``: one digest per zip entry's contents (zip metadata aside), the
  root ``zarr.json`` with the recorded source path and mtime removed (they
  name where and when the input was, not what the job computed).

With ``--compare``, prints the entries that differ from an earlier run and
exits 1 if any does.  Run it with the old code, then the new::

    git worktree add /tmp/before <old commit> && python3 -m venv /tmp/before/.venv \\
        && /tmp/before/.venv/bin/pip install -q /tmp/before
    /tmp/before/.venv/bin/python tools/check_identical.py --out before.json
    .venv/bin/python tools/check_identical.py --out after.json --compare before.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import time
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SAMPLE = HERE.parent / "data" / "test_data_77055_627760_LA93_IGN69.laz"

#: (name, subcommand and options, output suffix)
JOBS = (
    ("normals", ["normals"], ".laz"),
    ("don-exact", ["don", "--mode", "exact"], ".laz"),
    ("segment", ["segment"], ".laz"),
    ("compress", ["compress"], ".pcz"),
)


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def pcz_digests(path: Path) -> dict[str, str]:
    """One digest per entry of a ``.pcz`` zip; the root zarr.json without the source's path and mtime."""
    out = {}
    with zipfile.ZipFile(path) as z:
        for name in sorted(z.namelist()):
            data = z.read(name)
            if name == "zarr.json":
                meta = json.loads(data)
                source = meta.get("attributes", {}).get("source", {})
                for key in ("path", "mtime_ns"):
                    source.pop(key, None)
                data = json.dumps(meta, sort_keys=True).encode()
            out[name] = sha256(data)
    return out


def run_job(cli: list[str], args: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(cli + args, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"failed: {' '.join(args)}\n{proc.stderr}")
    return time.perf_counter() - t0


def fingerprints(inputs: dict[str, Path], workdir: Path) -> dict[str, object]:
    cli = [sys.executable, "-c", "from patchcloud.stream.cli import main; main()"]
    result: dict[str, object] = {}
    for label, path in inputs.items():
        for job, options, suffix in JOBS:
            out = workdir / f"{label}-{job}{suffix}"
            seconds = run_job(cli, options[:1] + [str(path), str(out), "--overwrite", "-q"] + options[1:])
            key = f"{label}/{job}"
            result[key] = pcz_digests(out) if suffix == ".pcz" else sha256(out.read_bytes())
            print(f"{key:<24} {seconds:6.1f} s", flush=True)
    return result


def compare(now: dict, before: dict) -> list[str]:
    bad = []
    for key in sorted(set(now) | set(before)):
        a, b = now.get(key), before.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            bad += [f"{key}:{e}" for e in sorted(set(a) | set(b)) if a.get(e) != b.get(e)]
        elif a != b:
            bad.append(key)
    return bad


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="where the fingerprints go (JSON)")
    ap.add_argument("--city-points", type=int, default=1_000_000, help="points of the synthetic city (0: none)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/check_identical"))
    ap.add_argument("--compare", type=Path, default=None, help="fingerprints of an earlier run")
    a = ap.parse_args()
    a.workdir.mkdir(parents=True, exist_ok=True)
    inputs = {"sample": SAMPLE}
    if a.city_points:
        city = a.workdir / f"city-{a.city_points}.laz"
        if not city.exists():
            subprocess.run([sys.executable, str(HERE / "city_las.py"), str(city), "--points", str(a.city_points)], check=True)
        inputs["city"] = city
    result = fingerprints(inputs, a.workdir)
    a.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    if a.compare is not None:
        bad = compare(result, json.loads(a.compare.read_text()))
        if bad:
            print("DIFFERENT: " + ", ".join(bad))
            sys.exit(1)
        print(f"identical: {len(result)} outputs, every byte (.pcz: every entry) the same as {a.compare}")


if __name__ == "__main__":
    main()
