"""A small PLY reader (ASCII and binary little-endian) for the reference meshes.

``read_ply(path)`` returns ``(vertices: dict[str, ndarray], faces: (F, 3) int64 or None)``.
Only triangle faces are kept (the Stanford meshes have only triangles).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_TYPES = {
    "char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
    "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
    "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8",
}


def read_ply(path: str | Path):
    data = Path(path).read_bytes()
    end = data.index(b"end_header") + len(b"end_header")
    end = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", "replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list]] = []
    for line in header:
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            if parts[1] == "list":
                elements[-1][2].append((parts[4], "list", _TYPES[parts[2]], _TYPES[parts[3]]))
            else:
                elements[-1][2].append((parts[2], _TYPES[parts[1]]))
    body = data[end:]
    vertices, faces = {}, None
    if fmt == "ascii":
        lines = body.decode("ascii").split("\n")
        pos = 0
        for name, count, props in elements:
            rows = lines[pos : pos + count]
            pos += count
            if name == "vertex":
                arr = np.array([r.split()[: len(props)] for r in rows], dtype=np.float64)
                vertices = {p[0]: arr[:, k] for k, p in enumerate(props)}
            elif name == "face":
                f = [r.split() for r in rows]
                faces = np.array([[int(x) for x in r[1:4]] for r in f if r and r[0] == "3"], dtype=np.int64)
        return vertices, faces
    if fmt != "binary_little_endian":
        raise ValueError(f"{path}: unsupported PLY format {fmt}")
    off = 0
    for name, count, props in elements:
        if all(len(p) == 2 for p in props):
            dt = np.dtype([(p[0], "<" + p[1]) for p in props])
            arr = np.frombuffer(body, dtype=dt, count=count, offset=off)
            off += dt.itemsize * count
            if name == "vertex":
                vertices = {p[0]: arr[p[0]].astype(np.float64) for p in props}
        else:  # faces: assume "list uchar int vertex_indices" with triangles only
            (_, _, ct, it), = [p for p in props if len(p) == 4]
            rec = np.dtype([("n", "<" + ct), ("v", "<" + it, (3,))])
            arr = np.frombuffer(body, dtype=rec, count=count, offset=off)
            off += rec.itemsize * count
            if name == "face":
                faces = arr["v"].astype(np.int64)
    return vertices, faces


def vertex_normals(xyz: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of a triangle mesh (zero rows for unused vertices)."""
    a, b, c = xyz[faces[:, 0]], xyz[faces[:, 1]], xyz[faces[:, 2]]
    fn = np.cross(b - a, c - a)  # length = 2 x area
    n = np.zeros_like(xyz)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    norm = np.linalg.norm(n, axis=1)
    return n / np.where(norm > 0, norm, 1.0)[:, None]


#: The reference meshes of ../shared/data: name and path below the data folder.
MESHES = (
    ("bunny", "mesh-stanford-bunny/reconstruction/bun_zipper.ply"),
    ("dragon", "mesh-dragon-decimated/dragon.ply"),
)


def mesh_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A mesh's used vertices ``(M, 3)`` and their unit normals ``(M, 3)``, outward.

    The normals are the file's ``nx, ny, nz`` when it has them, else the
    area-weighted vertex normals of its faces.  The mesh winding is consistent,
    so one global sign makes them outward: the one under which most of them
    point away from the centroid.
    """
    v, f = read_ply(path)
    xyz = np.column_stack([v["x"], v["y"], v["z"]])
    ref = np.column_stack([v["nx"], v["ny"], v["nz"]]) if "nx" in v else vertex_normals(xyz, f)
    ok = np.linalg.norm(ref, axis=1) > 0.5
    xyz, ref = xyz[ok], ref[ok] / np.linalg.norm(ref[ok], axis=1)[:, None]
    if np.mean(np.einsum("ij,ij->i", ref, xyz - xyz.mean(axis=0)) > 0) < 0.5:
        ref = -ref
    return xyz, ref
