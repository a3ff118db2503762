"""PLY point clouds: write and read coloured points in the Stanford polygon format.

A PLY file is a text header followed by the element data (Turk, "The PLY Polygon File
Format", 1994; http://paulbourke.net/dataformats/ply/)::

    ply
    format binary_little_endian 1.0
    comment written by dynslam_lab
    element vertex N
    property float x
    property float y
    property float z
    property uchar red
    property uchar green
    property uchar blue
    end_header
    <N records of 3 float32 + 3 uint8, little-endian>

Every viewer (MeshLab, CloudCompare, Open3D, trimesh, Blender) reads this vertex-only
layout. :func:`write_ply` writes it (binary by default, ASCII on request);
:func:`read_ply` reads back both encodings, float or double coordinates, with or without
colour, and any extra vertex properties (ignored).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["write_ply", "read_ply", "read_ply_header", "PlyHeader", "PlyError"]

# PLY scalar type names -> numpy dtypes (both the classic and the sized spellings).
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class PlyError(ValueError):
    """A PLY file is malformed or lacks the vertex coordinates; the message names the file."""


def write_ply(
    path: str | Path,
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    binary: bool = True,
    comment: str | None = None,
) -> Path:
    """Write points (and colours) as a vertex-only PLY file.

    Parameters
    ----------
    path : output file; its folder must exist.
    xyz : ``(N, 3)`` point coordinates (metres), written as float32.
    rgb : ``(N, 3)`` uint8 colours (RGB order), or None for no colour.
    binary : binary little-endian (default, ~15 bytes per point) or ASCII.
    comment : an optional one-line comment for the header.

    Returns
    -------
    Path of the written file.
    """
    path = Path(path)
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"write_ply({path}): xyz must have shape (N, 3), got {xyz.shape}")
    if not np.isfinite(xyz).all():
        raise ValueError(f"write_ply({path}): xyz holds {int((~np.isfinite(xyz)).any(axis=1).sum())} non-finite points")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != xyz.shape:
            raise ValueError(f"write_ply({path}): rgb must have shape {xyz.shape} like xyz, got {rgb.shape}")
        if rgb.dtype != np.uint8:
            raise ValueError(f"write_ply({path}): rgb must be uint8 (0..255), got {rgb.dtype}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    records = np.empty(len(xyz), dtype=fields)
    records["x"], records["y"], records["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if rgb is not None:
        records["red"], records["green"], records["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]

    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0"]
    if comment:
        header.append("comment " + " ".join(str(comment).split()))
    header.append(f"element vertex {len(xyz)}")
    header += [f"property float {c}" for c in "xyz"]
    if rgb is not None:
        header += [f"property uchar {c}" for c in ("red", "green", "blue")]
    header.append("end_header")
    with path.open("wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        if binary:
            fh.write(records.tobytes())
        else:
            fmt = "%.7g %.7g %.7g" + (" %d %d %d" if rgb is not None else "")
            cols = [xyz.astype(np.float32).astype(np.float64)] + ([rgb.astype(np.int64)] if rgb is not None else [])
            np.savetxt(fh, np.hstack(cols), fmt=fmt)
    return path


@dataclass(frozen=True)
class PlyHeader:
    """What a PLY header says about the vertex element.

    Attributes: ``format`` (``ascii``, ``binary_little_endian`` or ``binary_big_endian``),
    ``n_vertex``, ``properties`` (``(name, numpy type code)`` in file order), ``data_offset``
    (byte where the vertex data starts).
    """

    format: str
    n_vertex: int
    properties: tuple[tuple[str, str], ...]
    data_offset: int

    @property
    def has_color(self) -> bool:
        return {"red", "green", "blue"} <= {p[0] for p in self.properties}


def read_ply_header(path: str | Path) -> PlyHeader:
    """Parse and check the header of a PLY file (cheap: the vertex data is not read).

    Raises :class:`PlyError` naming the file for a missing file, a file that is not PLY, an
    unknown format or type, or a vertex element without ``x y z``.
    """
    path = Path(path)
    if not path.is_file():
        raise PlyError(f"{path}: PLY file not found")
    with path.open("rb") as fh:
        magic = fh.readline().strip()
        if magic != b"ply":
            raise PlyError(f"{path}: not a PLY file (first line {magic[:20]!r}, expected b'ply')")
        fmt = None
        n_vertex = None
        props: list[tuple[str, str]] = []
        current = None
        while True:
            line = fh.readline()
            if not line:
                raise PlyError(f"{path}: header has no end_header line")
            words = line.decode("ascii", errors="replace").split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "end_header":
                break
            if words[0] in ("format", "element", "property") and len(words) < 3:
                raise PlyError(f"{path}: malformed header line {line.strip()[:60]!r}")
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                current = words[1]
                if current == "vertex":
                    count = words[2]
                    if not count.isdigit():  # also refuses "-5", "1e15", "abc"
                        raise PlyError(f"{path}: vertex count {count!r} is not a whole number >= 0")
                    n_vertex = int(count)
                elif n_vertex is None:
                    raise PlyError(f"{path}: element {current!r} comes before 'vertex' (not supported)")
            elif words[0] == "property" and current == "vertex":
                if words[1] == "list":
                    raise PlyError(f"{path}: list properties in the vertex element are not supported")
                if words[1] not in _PLY_TYPES:
                    raise PlyError(f"{path}: unknown PLY type {words[1]!r}")
                props.append((words[2], _PLY_TYPES[words[1]]))
        offset = fh.tell()
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise PlyError(f"{path}: unknown PLY format {fmt!r}")
    if n_vertex is None:
        raise PlyError(f"{path}: no 'element vertex' in the header")
    names = [p[0] for p in props]
    if not {"x", "y", "z"} <= set(names):
        raise PlyError(f"{path}: vertex element lacks x, y, z properties (has {names})")
    return PlyHeader(fmt, n_vertex, tuple(props), offset)


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Read the vertices of a PLY file.

    Parameters
    ----------
    path : a PLY file (ASCII, binary little- or big-endian) whose first element is
        ``vertex`` with ``x y z`` properties; other elements after it (faces) are ignored.

    Returns
    -------
    xyz : ``(N, 3)`` float64 coordinates.
    rgb : ``(N, 3)`` uint8 colours, or None when the file has no ``red green blue``.
    """
    path = Path(path)
    head = read_ply_header(path)
    n_vertex, props = head.n_vertex, head.properties
    names = [p[0] for p in props]
    data_bytes = path.stat().st_size - head.data_offset  # checked before reading: a count of 10^15 must not allocate
    per_vertex = sum(np.dtype(t).itemsize for _, t in props) if head.format != "ascii" else 2 * len(props)
    if n_vertex * per_vertex > data_bytes:
        raise PlyError(f"{path}: truncated: the header announces {n_vertex} vertices, the file holds data for at most "
                       f"{data_bytes // per_vertex}")
    with path.open("rb") as fh:
        fh.seek(head.data_offset)
        if head.format == "ascii":
            data = np.loadtxt(fh, dtype=np.float64, max_rows=n_vertex, ndmin=2)
            if n_vertex and data.shape != (n_vertex, len(props)):
                raise PlyError(f"{path}: expected {n_vertex} vertex rows of {len(props)} values, got {data.shape}")
            col = {n: data[:, i] if n_vertex else np.zeros(0) for i, n in enumerate(names)}
        else:
            order = "<" if head.format == "binary_little_endian" else ">"
            dtype = np.dtype([(n, order + t) for n, t in props])
            raw = fh.read(dtype.itemsize * n_vertex)
            if len(raw) != dtype.itemsize * n_vertex:
                raise PlyError(f"{path}: truncated: {n_vertex} vertices need {dtype.itemsize * n_vertex} bytes, got {len(raw)}")
            rec = np.frombuffer(raw, dtype=dtype)
            col = {n: rec[n] for n in names}
    xyz = np.stack([col["x"], col["y"], col["z"]], axis=1).astype(np.float64)
    rgb = None
    if head.has_color:
        rgb = np.stack([col["red"], col["green"], col["blue"]], axis=1).astype(np.uint8)
    return xyz, rgb
