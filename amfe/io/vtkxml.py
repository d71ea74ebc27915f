"""VTK XML PolyData (``.vtp``) without VTK: write and read the files amfe makes.

amfe's frames are points (particle centres) joined by line cells (bonds), so
they are written as PolyData: ParaView's Tube and Glyph filters work on them
directly, where an UnstructuredGrid (``.vtu``) needs an Extract Surface first
(docs/viewing.md). Only numpy and the standard library are used, so a bare
machine writes the files and reads them back (``amfe view``'s matplotlib
fallback); VTK's own ``vtkXMLPolyDataReader`` reads them too (tested).

Format written
--------------
``<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian"
header_type="UInt64" compressor="vtkZLibDataCompressor">``; every numeric
array is inline ``format="binary"``: a base64 block header (number of blocks,
block size, size of the last block, compressed size of each block; UInt64)
followed by the base64 of the zlib blocks. Integer arrays (ids, connectivity)
are compressed (level 1: about 85 % smaller); float arrays are stored (level
0), because zlib shrinks float64 fields by 4 % at about 1 s per 14 MB
(measured on a 100 000-particle bed, docs/viewing.md). String arrays (field
data only) are ``format="ascii"``: each string as its character codes ending
in 0. Only lines are written as cells (no vertices, strips or polygons).
"""
import base64
import struct
import xml.etree.ElementTree as ET
import zlib

import numpy as np

from amfe.errors import AmfeError

BLOCK_BYTES = 1 << 20
"""Uncompressed bytes per zlib block (any size is valid VTK; 1 MiB keeps headers short)."""

_VTK_TYPES = {np.dtype("float64"): "Float64", np.dtype("float32"): "Float32",
              np.dtype("int64"): "Int64", np.dtype("int32"): "Int32",
              np.dtype("uint8"): "UInt8", np.dtype("int8"): "Int8"}
_NP_TYPES = {v: k for k, v in _VTK_TYPES.items()}
_NP_TYPES["UInt64"] = np.dtype("uint64")


class VtkXmlError(AmfeError):
    """An array this module does not write, or a file it cannot read back."""


def encode_binary(array, level=None):
    """Inline binary text of one array: base64(block header) + base64(zlib blocks).

    Parameters
    ----------
    array : numpy.ndarray
        Any shape; written C-contiguous, little-endian, in its own dtype.
    level : int, optional
        zlib level; default 1 for integer arrays and 0 (stored) for floats.

    Returns
    -------
    str
        The DataArray element's text.
    """
    if level is None:
        level = 0 if array.dtype.kind == "f" else 1
    raw = np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<"), copy=False).tobytes()
    packed = [zlib.compress(raw[k:k + BLOCK_BYTES], level)
              for k in range(0, len(raw), BLOCK_BYTES)]
    last = len(raw) % BLOCK_BYTES  # 0: the last block is full (or there is none)
    header = struct.pack(f"<{3 + len(packed)}Q", len(packed), BLOCK_BYTES, last,
                         *(len(p) for p in packed))
    return (base64.b64encode(header) + base64.b64encode(b"".join(packed))).decode("ascii")


def decode_binary(text, dtype, count):
    """Inverse of :func:`encode_binary`: a flat array of ``count`` values of ``dtype``."""
    text = "".join(text.split())
    nblocks = struct.unpack("<Q", base64.b64decode(text[:12])[:8])[0]
    hchars = 4 * ((8 * (3 + nblocks) + 2) // 3)
    header = struct.unpack(f"<{3 + nblocks}Q", base64.b64decode(text[:hchars]))
    data = base64.b64decode(text[hchars:])
    out, pos = [], 0
    for size in header[3:]:
        out.append(zlib.decompress(data[pos:pos + size]))
        pos += size
    arr = np.frombuffer(b"".join(out), dtype=np.dtype(dtype).newbyteorder("<"))
    if arr.size != count:
        raise VtkXmlError(f"array holds {arr.size} values, {count} expected")
    return arr.astype(np.dtype(dtype), copy=False)


def _data_array(parent, name, array):
    arr = np.asarray(array)
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8)
    if arr.dtype not in _VTK_TYPES:
        raise VtkXmlError(f"array {name!r}: dtype {arr.dtype} is not written")
    ncomp = 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))
    el = ET.SubElement(parent, "DataArray", type=_VTK_TYPES[arr.dtype], Name=name,
                       NumberOfComponents=str(ncomp), format="binary")
    el.text = encode_binary(arr)
    return el


def _string_array(parent, name, strings):
    codes = []
    for s in strings:
        codes.extend(str(b) for b in s.encode("utf-8"))
        codes.append("0")
    el = ET.SubElement(parent, "DataArray", type="String", Name=name,
                       NumberOfTuples=str(len(strings)), format="ascii")
    el.text = " ".join(codes)


def polydata_xml(points, lines, point_data, cell_data, field_data, vectors=None):
    """The bytes of a ``.vtp`` file: points joined by 2-point line cells.

    Parameters
    ----------
    points : ndarray (N, 3) float64
        Point coordinates.
    lines : ndarray (M, 2) int
        Point indices of each line cell; cell k is line k.
    point_data : dict of str -> ndarray (N,) or (N, k)
    cell_data : dict of str -> ndarray (M,) or (M, k)
    field_data : dict of str -> str, list of str, or ndarray (k,) / (1, k)
        A str or list of str becomes a String array (one tuple per string);
        a numeric array becomes one tuple of k components.
    vectors : str, optional
        Point array marked as the active vectors (ParaView's Warp By Vector
        and Glyph pick it by default).

    Returns
    -------
    bytes
        UTF-8 XML, ready to write.
    """
    points = np.asarray(points, dtype=np.float64)
    lines = np.asarray(lines, dtype=np.int64).reshape(-1, 2)
    n, m = points.shape[0], lines.shape[0]
    root = ET.Element("VTKFile", type="PolyData", version="1.0", byte_order="LittleEndian",
                      header_type="UInt64", compressor="vtkZLibDataCompressor")
    poly = ET.SubElement(root, "PolyData")
    if field_data:
        fd = ET.SubElement(poly, "FieldData")
        for name, value in field_data.items():
            if isinstance(value, str):
                _string_array(fd, name, [value])
            elif isinstance(value, (list, tuple)) and value and isinstance(value[0], str):
                _string_array(fd, name, list(value))
            else:
                arr = np.asarray(value)
                el = _data_array(fd, name, arr.reshape(1, -1))
                el.set("NumberOfTuples", "1")
    piece = ET.SubElement(poly, "Piece", NumberOfPoints=str(n), NumberOfVerts="0",
                          NumberOfLines=str(m), NumberOfStrips="0", NumberOfPolys="0")
    pd = ET.SubElement(piece, "PointData", **({"Vectors": vectors} if vectors else {}))
    for name, arr in point_data.items():
        _check_rows(name, arr, n, "point")
        _data_array(pd, name, arr)
    cd = ET.SubElement(piece, "CellData")
    for name, arr in cell_data.items():
        _check_rows(name, arr, m, "cell")
        _data_array(cd, name, arr)
    _data_array(ET.SubElement(piece, "Points"), "Points", points)
    el = ET.SubElement(piece, "Lines")
    _data_array(el, "connectivity", lines.reshape(-1))
    _data_array(el, "offsets", np.arange(2, 2 * m + 1, 2, dtype=np.int64))
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def _check_rows(name, arr, rows, what):
    if np.asarray(arr).shape[:1] != (rows,):
        raise VtkXmlError(f"{what} array {name!r} has shape {np.shape(arr)}, "
                          f"{rows} rows expected")


def _read_array(el, count_tuples=None):
    vtype = el.get("type")
    if vtype == "String":
        codes = [int(c) for c in (el.text or "").split()]
        out, cur = [], bytearray()
        for c in codes:
            if c == 0:
                out.append(cur.decode("utf-8"))
                cur = bytearray()
            else:
                cur.append(c)
        return out
    ncomp = int(el.get("NumberOfComponents", "1"))
    tuples = int(el.get("NumberOfTuples", count_tuples if count_tuples is not None else -1))
    fmt = el.get("format")
    if vtype not in _NP_TYPES:
        raise VtkXmlError(f"array {el.get('Name')!r}: type {vtype} not supported")
    if fmt == "binary":
        flat = decode_binary(el.text or "", _NP_TYPES[vtype], tuples * ncomp)
    elif fmt == "ascii":
        flat = np.array((el.text or "").split(), dtype=_NP_TYPES[vtype])
    else:
        raise VtkXmlError(f"array {el.get('Name')!r}: format {fmt!r} not supported")
    return flat.reshape(tuples, ncomp) if ncomp > 1 else flat


def read_polydata(path, arrays=None):
    """Read a ``.vtp`` written by :func:`polydata_xml` (numpy only).

    Parameters
    ----------
    path : str or path-like
    arrays : iterable of str, optional
        Decode only these point and cell arrays (all when None): the others
        are skipped, which saves most of the time on large files.

    Returns
    -------
    dict
        ``points`` (N, 3), ``lines`` (M, 2) int64, ``point_data`` {name:
        (N,) or (N, k)}, ``cell_data`` {name: (M,) or (M, k)}, ``field_data``
        {name: list of str or (k,) array}.

    Raises
    ------
    VtkXmlError
        Not PolyData as this module writes it (another compressor, big-endian,
        UInt32 headers), or holding cells other than 2-point lines.
    """
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise VtkXmlError(f"cannot read {path}: {exc}") from None
    if root.get("type") != "PolyData":
        raise VtkXmlError(f"{path}: not VTK XML PolyData")
    if root.get("compressor") != "vtkZLibDataCompressor" or \
            root.get("header_type", "UInt32") != "UInt64" or \
            root.get("byte_order") != "LittleEndian":
        raise VtkXmlError(f"{path}: not written by amfe (only zlib-blocked little-endian "
                          "arrays with UInt64 headers are read)")
    piece = root.find("PolyData/Piece")
    if piece is None or piece.find("Points/DataArray") is None:
        raise VtkXmlError(f"{path}: a PolyData file without points")
    n, m = int(piece.get("NumberOfPoints")), int(piece.get("NumberOfLines", "0"))
    wanted = None if arrays is None else set(arrays)

    def data(section, rows):
        return {e.get("Name"): _read_array(e, rows) for e in piece.findall(f"{section}/DataArray")
                if wanted is None or e.get("Name") in wanted}

    out = {"points": _read_array(piece.find("Points/DataArray"), n).reshape(n, 3),
           "point_data": data("PointData", n), "cell_data": data("CellData", m),
           "field_data": {}}
    for e in root.findall("PolyData/FieldData/DataArray"):
        val = _read_array(e)
        out["field_data"][e.get("Name")] = val if isinstance(val, list) else np.ravel(val)
    conn = {e.get("Name"): e for e in piece.findall("Lines/DataArray")}
    if m:
        offsets = _read_array(conn["offsets"], m)
        if not np.array_equal(offsets, np.arange(2, 2 * m + 1, 2)):
            raise VtkXmlError(f"{path}: only 2-point line cells are read")
        out["lines"] = _read_array(conn["connectivity"], 2 * m).reshape(m, 2).astype(np.int64)
    else:
        out["lines"] = np.zeros((0, 2), np.int64)
    return out
