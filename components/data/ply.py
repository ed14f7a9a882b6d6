"""A small PLY point reader (ASCII and binary), enough for seed point clouds.

Only the ``vertex`` element is returned: ``x, y, z`` and, when present, ``red, green, blue``.
Written here rather than pulling in a mesh library for one file format.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tridehaze_plugin.errors import DataError

_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_COLOR_NAMES = (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"), ("r", "g", "b"))


@dataclass
class _Prop:
    name: str
    dtype: str  # numpy type code, e.g. "f4"
    count_dtype: str | None = None  # set for list properties


@dataclass
class _Element:
    name: str
    count: int
    props: list[_Prop]


def read_ply_vertex(
    path: Path, what: str = "PLY file", not_found_fix: str | None = None, invalid_fix: str = "re-export it"
) -> np.ndarray:
    """The ``vertex`` element of a PLY file as a structured array; a one-line DataError otherwise.

    ``what`` names the file in messages (e.g. "point cloud"); shared by every PLY reader.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{what} not found", where=str(path), fix=not_found_fix) from None
    except OSError as exc:
        raise DataError(f"{what} cannot be read ({exc.strerror or exc})", where=str(path)) from None
    try:
        fmt, elements, body = _parse_header(data)
        return _read_vertex(fmt, elements, body)
    except (ValueError, KeyError, IndexError, UnicodeDecodeError) as exc:
        raise DataError(f"{what} is not a valid PLY file ({exc})", where=str(path), fix=invalid_fix) from None


def read_ply_points(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """PLY file -> (xyz [M, 3] float64, rgb [M, 3] uint8 or None)."""
    path = Path(path)
    vertex = read_ply_vertex(
        path, "point cloud", not_found_fix="fix ply_file_path or remove it", invalid_fix="re-export it as PLY"
    )
    names = vertex.dtype.names or ()
    if not all(k in names for k in ("x", "y", "z")):
        raise DataError(
            "point cloud vertices lack x, y, z", where=str(path), fix="re-export it with positions"
        )
    xyz = np.stack([vertex[k].astype(np.float64) for k in ("x", "y", "z")], axis=1)  # [M, 3]
    rgb = None
    for keys in _COLOR_NAMES:
        if all(k in names for k in keys):
            cols = np.stack([vertex[k] for k in keys], axis=1)  # [M, 3]
            if np.issubdtype(cols.dtype, np.floating):
                scale = 255.0 if cols.size and float(np.nanmax(cols)) <= 1.0 else 1.0
                cols = np.clip(np.nan_to_num(cols) * scale + 0.5, 0, 255)
            rgb = np.clip(cols, 0, 255).astype(np.uint8)
            break
    return xyz, rgb


def _parse_header(data: bytes) -> tuple[str, list[_Element], bytes]:
    if not data.startswith(b"ply"):
        raise ValueError("missing 'ply' magic")
    end = data.find(b"end_header")
    if end < 0:
        raise ValueError("missing end_header")
    nl = data.find(b"\n", end)
    body = data[nl + 1 :] if nl >= 0 else b""
    fmt = ""
    elements: list[_Element] = []
    for raw in data[:end].decode("ascii").splitlines()[1:]:
        tok = raw.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append(_Element(tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if not elements:
                raise ValueError("property before any element")
            if tok[1] == "list":
                elements[-1].props.append(_Prop(tok[4], _TYPES[tok[3]], _TYPES[tok[2]]))
            else:
                elements[-1].props.append(_Prop(tok[2], _TYPES[tok[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"unknown format {fmt!r}")
    if not any(e.name == "vertex" for e in elements):
        raise ValueError("no vertex element")
    return fmt, elements, body


def _read_vertex(fmt: str, elements: list[_Element], body: bytes) -> np.ndarray:
    if fmt == "ascii":
        return _read_vertex_ascii(elements, body)
    endian = "<" if fmt == "binary_little_endian" else ">"
    offset = 0
    for el in elements:
        if el.name == "vertex":
            if any(p.count_dtype for p in el.props):
                raise ValueError("list properties in the vertex element are not supported")
            dtype = np.dtype([(p.name, endian + p.dtype) for p in el.props])
            need = dtype.itemsize * el.count
            if offset + need > len(body):
                raise ValueError(f"file truncated: {el.count} vertices need {need} bytes")
            return np.frombuffer(body, dtype=dtype, count=el.count, offset=offset)
        offset = _skip_binary(el, body, offset, endian)
    raise ValueError("no vertex element")


def _skip_binary(el: _Element, body: bytes, offset: int, endian: str) -> int:
    """Byte offset just past ``el`` (a non-vertex element that comes before the vertices)."""
    if not any(p.count_dtype for p in el.props):
        return offset + el.count * sum(np.dtype(p.dtype).itemsize for p in el.props)
    for _ in range(el.count):
        for p in el.props:
            if p.count_dtype:
                n = int(np.frombuffer(body, endian + p.count_dtype, count=1, offset=offset)[0])
                offset += np.dtype(p.count_dtype).itemsize + n * np.dtype(p.dtype).itemsize
            else:
                offset += np.dtype(p.dtype).itemsize
    return offset


def _read_vertex_ascii(elements: list[_Element], body: bytes) -> np.ndarray:
    lines = body.decode("ascii").splitlines()
    start = 0
    for el in elements:
        if el.name == "vertex":
            rows = lines[start : start + el.count]
            if len(rows) < el.count:
                raise ValueError(f"file truncated: expected {el.count} vertex lines, found {len(rows)}")
            dtype = np.dtype([(p.name, p.dtype) for p in el.props])
            if el.count == 0:
                return np.zeros(0, dtype=dtype)
            table = np.loadtxt(io.StringIO("\n".join(rows)), dtype=np.float64, ndmin=2)  # [M, P]
            if table.shape[1] != len(el.props):
                raise ValueError("vertex lines do not match the header's properties")
            out = np.zeros(el.count, dtype=dtype)
            for j, p in enumerate(el.props):
                out[p.name] = table[:, j]
            return out
        start += el.count
    raise ValueError("no vertex element")


def write_ply_points(
    path: Path, xyz: np.ndarray, rgb: np.ndarray | None = None, *, binary: bool = True
) -> None:
    """Write points [M, 3] (+ colours [M, 3] uint8) as PLY; used by tests and export tools."""
    xyz = np.asarray(xyz, dtype=np.float32)
    props = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if rgb is not None:
        props += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    header = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        f"element vertex {len(xyz)}",
    ]
    header += [f"property {'float' if t == 'f4' else 'uchar'} {n}" for n, t in props]
    header.append("end_header")
    arr = np.zeros(len(xyz), dtype=np.dtype([(n, "<" + t) for n, t in props]))
    for j, k in enumerate("xyz"):
        arr[k] = xyz[:, j]
    if rgb is not None:
        for j, k in enumerate(("red", "green", "blue")):
            arr[k] = np.asarray(rgb)[:, j]
    if binary:
        body = arr.tobytes()
    else:
        rows = [" ".join(str(v) for v in row) for row in arr.tolist()]
        body = ("\n".join(rows) + "\n").encode("ascii") if rows else b""
    Path(path).write_bytes(("\n".join(header) + "\n").encode("ascii") + body)
