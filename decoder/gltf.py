"""glTF 2.0 scenes with 3D Gaussian splats: plain ``KHR_gaussian_splatting`` read and write,
and the ``.glb`` that carries a .gsz (``EXT_gaussian_splatting_compression_gsz``).

    cloud = read_gltf("scene.glb")                 # or .gltf; any KHR_gaussian_splatting scene
    write_gltf(cloud, "scene.glb")                 # plain KHR_gaussian_splatting (float32)
    glb = gsz_glb_bytes(open("scene.gsz", "rb").read())   # the .gsz wrapped in a .glb

The glTF document model, its JSON and the GLB packing come from pygltflib (the ``gltf`` extra,
imported on first use: the decoder core never needs it; a .glb-wrapped .gsz decodes without it
through ``gsz.decoder.decode``).  The value conventions are :mod:`gsz.decoder.khr`'s; the
format is specified in ``format_spec/GLTF.md``.
"""
from __future__ import annotations

import base64
import json
import os
import urllib.parse

import numpy as np

from .cloud import GaussianCloud
from .container import DEFAULT_MAX_GAUSSIANS, FRAME_RDF, FRAME_UNSPECIFIED, read_container
from .errors import GltfFormatError, GszError, GszFormatError
from .glb import EXT_GSZ, KHR_GAUSSIAN_SPLATTING, gsz_primitives, is_glb, parse_glb
from .io_util import atomic_write, check_input_file, read_all
from .khr import KhrSplats, color0, dc_from_color, from_khr, to_khr, transform

#: the extension object gsz writes: the ratified defaults, spelled out (colorSpace is required)
KHR_PROPERTIES = {"kernel": "ellipse", "colorSpace": "srgb_rec709_display",
                  "projection": "perspective", "sortingMethod": "cameraDistance"}
#: extensions a file may require that gsz reads (quantised attributes are read as floats)
READABLE_REQUIRED = {KHR_GAUSSIAN_SPLATTING, EXT_GSZ, "KHR_mesh_quantization"}
FLOAT, ARRAY_BUFFER, POINTS = 5126, 34962, 0
#: componentType -> (numpy dtype, divisor of a normalized value; None: not normalizable)
_COMPONENTS = {5120: ("<i1", 127.0), 5121: ("<u1", 255.0), 5122: ("<i2", 32767.0),
               5123: ("<u2", 65535.0), 5125: ("<u4", None), 5126: ("<f4", None)}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_SH_COUNT = {1: 3, 2: 5, 3: 7}
ATTR = KHR_GAUSSIAN_SPLATTING + ":"


def pygltflib():
    """The pygltflib module, or a one-line GszError naming the extra that installs it."""
    try:
        import pygltflib as lib
    except ImportError:
        raise GszError("glTF support needs pygltflib: pip install 'gsz[gltf]'") from None
    return lib


def sh_semantics(degree: int) -> list:
    """The SH_DEGREE_l_COEF_n attribute names of bands 1..degree, in sh_rest order."""
    return [f"{ATTR}SH_DEGREE_{band}_COEF_{n}" for band in range(1, degree + 1) for n in range(_SH_COUNT[band])]


# ------------------------------------------------------------------------------------ writing
def _document(lib, extensions_used: list, extensions_required: list):
    doc = lib.GLTF2(asset=lib.Asset(generator=f"gsz {_version()}", version="2.0"),
                    scene=0, scenes=[lib.Scene(nodes=[0])], nodes=[lib.Node(mesh=0)])
    doc.extensionsUsed = list(extensions_used)
    doc.extensionsRequired = list(extensions_required)
    return doc


def _version() -> str:
    from .. import __version__
    return __version__


def khr_document(s: KhrSplats, *, color: bool = True):
    """A pygltflib ``GLTF2`` holding ``s`` as one plain ``KHR_gaussian_splatting`` POINTS
    primitive (float32 attributes, one tightly packed bufferView each, plus a uint8 COLOR_0
    fallback when ``color``), its binary blob set."""
    lib = pygltflib()
    doc = _document(lib, [KHR_GAUSSIAN_SPLATTING], [])
    columns = [("POSITION", s.positions, "VEC3"), (f"{ATTR}SCALE", s.scales, "VEC3"),
               (f"{ATTR}ROTATION", s.rotations, "VEC4"), (f"{ATTR}OPACITY", s.opacities[:, None], "SCALAR"),
               (f"{ATTR}SH_DEGREE_0_COEF_0", s.sh_dc, "VEC3")]
    columns += [(name, s.sh_rest[:, k], "VEC3") for k, name in enumerate(sh_semantics(s.sh_degree))]
    if color:
        columns.append(("COLOR_0", color0(s), "VEC4"))
    attributes, blob = {}, bytearray()
    for i, (name, values, kind) in enumerate(columns):
        data = np.ascontiguousarray(values, values.dtype.newbyteorder("<")).tobytes()
        doc.bufferViews.append(lib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data),
                                              target=ARRAY_BUFFER))
        acc = lib.Accessor(bufferView=i, componentType=5121 if values.dtype == np.uint8 else FLOAT,
                           normalized=values.dtype == np.uint8 or None, count=len(s), type=kind)
        if name == "POSITION":      # glTF requires POSITION bounds (exact float32 values)
            acc.min = [float(v) for v in s.positions.min(axis=0)] if len(s) else [0.0] * 3
            acc.max = [float(v) for v in s.positions.max(axis=0)] if len(s) else [0.0] * 3
        doc.accessors.append(acc)
        attributes[name] = i
        blob += data + b"\0" * (-len(data) % 4)
    doc.buffers.append(lib.Buffer(byteLength=len(blob)))
    doc.meshes.append(lib.Mesh(primitives=[lib.Primitive(
        attributes=lib.Attributes(**attributes), mode=POINTS,
        extensions={KHR_GAUSSIAN_SPLATTING: dict(KHR_PROPERTIES)})]))
    doc.set_binary_blob(bytes(blob))
    return doc


def _serialise(doc, binary: bool) -> bytes:
    lib = pygltflib()
    if binary:
        return b"".join(doc.save_to_bytes())
    doc.convert_buffers(lib.BufferFormat.DATAURI)     # one self-contained, atomically written file
    return doc.gltf_to_json().encode("utf-8")


def gltf_bytes(cloud: GaussianCloud, *, binary: bool = True, frame: int = FRAME_RDF, color: bool = True,
               name=None) -> bytes:
    """``cloud`` (values in the .gsz ``frame``) as a plain ``KHR_gaussian_splatting`` .glb
    (``binary``) or .gltf with its buffer embedded as a data URI; deterministic bytes."""
    return _serialise(khr_document(to_khr(cloud, frame, name=name), color=color), binary)


def write_gltf(cloud: GaussianCloud, path, *, frame: int = FRAME_RDF, color: bool = True,
               binary: bool | None = None) -> None:
    """Write ``cloud`` as plain ``KHR_gaussian_splatting`` glTF, atomically: a .glb unless
    ``binary`` is False or (when None) ``path`` ends in .gltf."""
    path = os.fspath(path)
    if binary is None:
        binary = not path.lower().endswith(".gltf")
    atomic_write(path, gltf_bytes(cloud, binary=binary, frame=frame, color=color, name=path))


def gsz_glb_bytes(payload) -> bytes:
    """The .glb that carries the .gsz ``payload`` (GLTF.md §3): one POINTS primitive whose
    ``KHR_gaussian_splatting`` object holds ``EXT_gaussian_splatting_compression_gsz`` with the
    bufferView of the payload (first in the BIN chunk, so a streaming loader reaches layer 0
    early), and data-less accessors declaring what decoding yields.  Both extensions are
    required: the accessors hold no values without the decoder."""
    lib = pygltflib()
    header = read_container(payload).header          # checksums verified: wrap only sound files
    n, degree = int(header.num_gaussians), int(header.sh_degree)
    doc = _document(lib, [KHR_GAUSSIAN_SPLATTING, EXT_GSZ], [KHR_GAUSSIAN_SPLATTING, EXT_GSZ])
    doc.buffers.append(lib.Buffer(byteLength=len(payload)))
    doc.bufferViews.append(lib.BufferView(buffer=0, byteOffset=0, byteLength=len(payload)))
    from .khr import FRAME_TO_GLTF
    flip = np.diag(FRAME_TO_GLTF.get(int(header.frame), FRAME_TO_GLTF[FRAME_RDF]))
    corners = np.array([header.bbox_min, header.bbox_max], np.float32) * flip.astype(np.float32)
    kinds = [("POSITION", "VEC3"), (f"{ATTR}SCALE", "VEC3"), (f"{ATTR}ROTATION", "VEC4"),
             (f"{ATTR}OPACITY", "SCALAR"), (f"{ATTR}SH_DEGREE_0_COEF_0", "VEC3")]
    kinds += [(name, "VEC3") for name in sh_semantics(degree)]
    attributes = {}
    for i, (name, kind) in enumerate(kinds):
        acc = lib.Accessor(byteOffset=None, componentType=FLOAT, normalized=None, count=n, type=kind)
        if name == "POSITION":
            acc.min = [float(v) for v in corners.min(axis=0)]
            acc.max = [float(v) for v in corners.max(axis=0)]
        doc.accessors.append(acc)
        attributes[name] = i
    ext = dict(KHR_PROPERTIES, extensions={EXT_GSZ: {"bufferView": 0}})
    doc.meshes.append(lib.Mesh(primitives=[lib.Primitive(
        attributes=lib.Attributes(**attributes), mode=POINTS, extensions={KHR_GAUSSIAN_SPLATTING: ext})]))
    doc.set_binary_blob(bytes(payload))
    return _serialise(doc, True)


# ------------------------------------------------------------------------------------ reading
def _load(data, path):
    """(pygltflib GLTF2, JSON dict, [buffer bytes]) of a .glb or .gltf held in ``data``."""
    lib = pygltflib()
    mv = memoryview(data).cast("B")
    bin_chunk = None
    if is_glb(mv):
        try:
            glb = parse_glb(mv)
        except GszFormatError as e:          # a glTF error here, not a .gsz one
            raise GltfFormatError(str(e).removeprefix(f"{path}: "), path) from None
        doc_dict = glb.doc
        if glb.bin_offset is not None:
            bin_chunk = mv[glb.bin_offset:glb.bin_offset + glb.bin_length]
    else:
        try:
            doc_dict = json.loads(bytes(mv).decode("utf-8-sig"))
        except (UnicodeDecodeError, ValueError, RecursionError) as e:
            raise GltfFormatError(f"is not a .glb and not valid glTF JSON ({type(e).__name__})", path) from None
        if not isinstance(doc_dict, dict):
            raise GltfFormatError("glTF JSON is not an object", path)
    try:
        doc = lib.GLTF2.from_json(json.dumps(doc_dict), infer_missing=True)
    except Exception as e:                   # pygltflib/dataclasses-json raise many types on bad JSON
        raise GltfFormatError(f"malformed glTF document ({type(e).__name__}: {e})", path) from None
    version = str(getattr(doc.asset, "version", "") or "")
    if not version.startswith("2."):
        raise GltfFormatError(f"asset.version is {version!r}; gsz reads glTF 2.x", path)
    unknown = [e for e in (doc.extensionsRequired or []) if e not in READABLE_REQUIRED]
    if unknown:
        raise GltfFormatError(f"requires extension {', '.join(map(str, unknown))}, which gsz does not read", path)
    return doc, doc_dict, [_buffer(doc, i, bin_chunk, path) for i in range(len(doc.buffers or []))]


def _buffer(doc, i: int, bin_chunk, path) -> memoryview:
    b = doc.buffers[i]
    uri, length = b.uri, b.byteLength
    if not isinstance(length, int) or isinstance(length, bool) or length < 0:
        raise GltfFormatError(f"buffers[{i}].byteLength is not a non-negative integer", path)
    if uri is None:
        if i != 0 or bin_chunk is None:
            raise GltfFormatError(f"buffers[{i}] has no uri and there is no GLB BIN chunk for it", path)
        data = bin_chunk
    elif uri.startswith("data:"):
        head, _, body = uri.partition(",")
        if not head.endswith(";base64"):
            raise GltfFormatError(f"buffers[{i}]: only base64 data URIs are read", path)
        try:
            data = memoryview(base64.b64decode(body, validate=True))
        except ValueError:
            raise GltfFormatError(f"buffers[{i}]: bad base64 data URI", path) from None
    else:
        if path is None or "://" in uri or os.path.isabs(urllib.parse.unquote(uri)):
            raise GltfFormatError(f"buffers[{i}]: uri {uri[:60]!r} is not a file beside the glTF", path)
        file = os.path.join(os.path.dirname(os.path.abspath(path)), urllib.parse.unquote(uri))
        check_input_file(file, GltfFormatError)
        with open(file, "rb") as f:
            data = memoryview(f.read())
    if len(data) < length:
        raise GltfFormatError(f"buffers[{i}] holds {len(data):,} bytes, fewer than its byteLength {length:,}", path)
    return data


def _int(value, what: str, path, low: int = 0, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low or (high is not None and value >= high):
        bound = f" below {high}" if high is not None else ""
        raise GltfFormatError(f"{what} is {value!r}, not an integer >= {low}{bound}", path)
    return value


def _view_array(doc, buffers, view_index, offset, count: int, dtype, width: int, what, path) -> np.ndarray:
    """[count, width] values of ``dtype`` read from bufferView ``view_index`` at ``offset``."""
    view = doc.bufferViews[_int(view_index, f"{what}.bufferView", path, 0, len(doc.bufferViews or []))]
    data = buffers[_int(view.buffer, f"{what}: bufferView.buffer", path, 0, len(buffers))]
    start = _int(view.byteOffset or 0, f"{what}: bufferView.byteOffset", path) + _int(offset or 0, f"{what}.byteOffset", path)
    end = _int(view.byteOffset or 0, "bufferView.byteOffset", path) + _int(view.byteLength, f"{what}: bufferView.byteLength", path)
    elem = dtype.itemsize * width
    stride = elem if view.byteStride is None else _int(view.byteStride, f"{what}: bufferView.byteStride", path, elem)
    if end > len(data) or (count and start + stride * (count - 1) + elem > end):
        raise GltfFormatError(f"{what}: {count:,} elements run past the end of their bufferView or buffer", path)
    if not count:
        return np.zeros((0, width), dtype)
    return np.ndarray((count, width), dtype=dtype, buffer=data, offset=start, strides=(stride, dtype.itemsize)).copy()


def read_accessor(doc, buffers, index, what: str, path=None, *, kinds=("VEC3",)) -> np.ndarray:
    """[count, width] float32 values of accessor ``index`` (normalized integers converted as
    glTF 2.0 §3.11 says; sparse substitution applied; no bufferView means zeros)."""
    acc = doc.accessors[_int(index, what, path, 0, len(doc.accessors or []))]
    what = f"{what} (accessor {index})"
    if acc.type not in kinds:
        raise GltfFormatError(f"{what} has type {acc.type!r}, expected {' or '.join(kinds)}", path)
    if acc.componentType not in _COMPONENTS:
        raise GltfFormatError(f"{what} has componentType {acc.componentType!r}", path)
    dtype, divisor = np.dtype(_COMPONENTS[acc.componentType][0]), _COMPONENTS[acc.componentType][1]
    width, count = _WIDTH[acc.type], _int(acc.count, f"{what}.count", path)
    if acc.bufferView is None:
        if count > DEFAULT_MAX_GAUSSIANS:          # zeros cost memory the file never paid for
            raise GltfFormatError(f"{what} declares {count:,} elements without data, above the "
                                  f"{DEFAULT_MAX_GAUSSIANS:,} gsz reads", path)
        values = np.zeros((count, width), dtype)
    else:
        values = _view_array(doc, buffers, acc.bufferView, acc.byteOffset, count, dtype, width, what, path)
    if acc.sparse is not None:
        sp = acc.sparse
        k = _int(sp.count, f"{what}.sparse.count", path, 1, count + 1)
        idx_type = _COMPONENTS.get(sp.indices.componentType, (None,))[0]
        if sp.indices.componentType not in (5121, 5123, 5125):
            raise GltfFormatError(f"{what}: sparse indices componentType {sp.indices.componentType!r}", path)
        idx = _view_array(doc, buffers, sp.indices.bufferView, sp.indices.byteOffset, k, np.dtype(idx_type), 1,
                          f"{what}.sparse.indices", path)[:, 0]
        if (idx >= count).any():
            raise GltfFormatError(f"{what}: sparse index beyond count {count}", path)
        values[idx] = _view_array(doc, buffers, sp.values.bufferView, sp.values.byteOffset, k, dtype, width,
                                  f"{what}.sparse.values", path)
    if acc.normalized:
        if divisor is None:
            raise GltfFormatError(f"{what} is normalized but its componentType cannot be", path)
        return np.maximum(values.astype(np.float64) / divisor, -1.0).astype(np.float32)
    return values.astype(np.float32)


def _splats(doc, buffers, prim, where: str, path) -> KhrSplats:
    """The KHR attributes of one plain ``KHR_gaussian_splatting`` primitive (COLOR_0 stands in
    for a missing SH_DEGREE_0_COEF_0 and its alpha for a missing OPACITY, as the extension's
    fallback describes)."""
    attrs = {k: v for k, v in vars(prim.attributes).items() if v is not None}
    if prim.mode != POINTS:
        raise GltfFormatError(f"{where}: a {KHR_GAUSSIAN_SPLATTING} primitive must have mode POINTS (0), "
                              f"not {prim.mode!r}", path)

    def get(name, kinds=("VEC3",)):
        return read_accessor(doc, buffers, attrs[name], f"{where} {name}", path, kinds=kinds) if name in attrs else None

    for name in ("POSITION", f"{ATTR}SCALE", f"{ATTR}ROTATION"):
        if name not in attrs:
            raise GltfFormatError(f"{where} has no {name} attribute", path)
    pos, scale, rot = get("POSITION"), get(f"{ATTR}SCALE"), get(f"{ATTR}ROTATION", ("VEC4",))
    color = get("COLOR_0", ("VEC3", "VEC4"))
    opacity, dc = get(f"{ATTR}OPACITY", ("SCALAR",)), get(f"{ATTR}SH_DEGREE_0_COEF_0")
    if opacity is None:
        if color is None or color.shape[1] != 4:
            raise GltfFormatError(f"{where} has neither {ATTR}OPACITY nor an RGBA COLOR_0", path)
        opacity = color[:, 3:]
    if dc is None:
        if color is None:
            raise GltfFormatError(f"{where} has neither {ATTR}SH_DEGREE_0_COEF_0 nor COLOR_0", path)
        dc = dc_from_color(color[:, :3])
    degree = 0
    while degree < 3 and any(n.startswith(f"{ATTR}SH_DEGREE_{degree + 1}_") for n in attrs):
        degree += 1
    names = sh_semantics(degree)
    missing = [n for n in names if n not in attrs]
    stray = [n for n in attrs if n.startswith(f"{ATTR}SH_DEGREE_") and n not in names
             and n != f"{ATTR}SH_DEGREE_0_COEF_0"]
    if missing or stray:
        raise GltfFormatError(f"{where}: spherical harmonics are not complete degrees ("
                              + (f"missing {missing[0]}" if missing else f"unexpected {stray[0]}") + ")", path)
    rest = np.stack([get(n) for n in names], axis=1) if names else np.zeros((len(pos), 0, 3), np.float32)
    for name, arr in (("SCALE", scale), ("ROTATION", rot), ("OPACITY", opacity), ("SH", dc), ("SH", rest)):
        if len(arr) != len(pos):
            raise GltfFormatError(f"{where}: {name} has {len(arr):,} elements, POSITION {len(pos):,}", path)
    return KhrSplats(pos, scale, rot, opacity[:, 0], dc, rest)


def _node_matrix(node) -> np.ndarray:
    if node.matrix:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T      # column-major in glTF
    t = np.asarray(node.translation or (0, 0, 0), np.float64)
    x, y, z, w = np.asarray(node.rotation or (0, 0, 0, 1), np.float64)
    s = np.asarray(node.scale or (1, 1, 1), np.float64)
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot * s, t
    return m


def mesh_instances(doc, path=None) -> list:
    """[(mesh index, 4x4 world matrix)] of the default scene (scene 0 when none is named; every
    mesh once with the identity when the file has no scenes)."""
    meshes = len(doc.meshes or [])
    if not doc.scenes:
        return [(m, np.eye(4)) for m in range(meshes)]
    scene = doc.scenes[_int(0 if doc.scene is None else doc.scene, "scene", path, 0, len(doc.scenes))]
    out, seen = [], set()
    stack = [(n, np.eye(4)) for n in reversed(scene.nodes or [])]
    while stack:
        index, parent = stack.pop()
        node = doc.nodes[_int(index, "a scene's node", path, 0, len(doc.nodes or []))]
        if index in seen:
            raise GltfFormatError(f"node {index} is reached twice (the node graph is not a forest)", path)
        seen.add(index)
        world = parent @ _node_matrix(node)
        if node.mesh is not None:
            out.append((_int(node.mesh, f"nodes[{index}].mesh", path, 0, meshes), world))
        stack.extend((c, world) for c in reversed(node.children or []))
    return out


def _is_splat(prim) -> bool:
    return isinstance(prim.extensions, dict) and KHR_GAUSSIAN_SPLATTING in prim.extensions


def read_gltf_bytes(data, path=None) -> GaussianCloud:
    """The splats of a .glb / .gltf held in ``data`` as one graphdeco cloud (RDF frame): every
    ``KHR_gaussian_splatting`` primitive of the default scene, node transforms baked in, clouds
    of several primitives concatenated (SH padded to the highest degree).  A gsz-compressed
    primitive is decoded (:func:`gsz.decoder.decode`)."""
    try:
        return _read(data, path)
    except MemoryError:
        raise GltfFormatError("declares more data than can be allocated", path) from None
    except (TypeError, ValueError, KeyError, IndexError, AttributeError) as e:
        if isinstance(e, GszError):
            raise
        raise GltfFormatError(f"malformed glTF ({type(e).__name__}: {e})", path) from None


def _read(data, path) -> GaussianCloud:
    doc, doc_dict, buffers = _load(data, path)
    clouds, decoded = [], []
    gsz = {(m, p) for m, p, _ in gsz_primitives(doc_dict)}
    for mesh, world in mesh_instances(doc, path):
        for p, prim in enumerate(doc.meshes[mesh].primitives or []):
            if not _is_splat(prim):
                continue
            where = f"meshes[{mesh}].primitives[{p}]"
            props = prim.extensions[KHR_GAUSSIAN_SPLATTING]
            if isinstance(props, dict) and props.get("kernel", "ellipse") != "ellipse":
                raise GltfFormatError(f"{where}: kernel {props.get('kernel')!r} is not the ellipse kernel gsz reads", path)
            space = props.get("colorSpace") if isinstance(props, dict) else None
            if space not in (None, KHR_PROPERTIES["colorSpace"]):
                import warnings
                warnings.warn(f"{path or 'glTF'}: {where} has colorSpace {space!r}; gsz keeps its SH "
                              f"coefficients as they are and writes glTF as {KHR_PROPERTIES['colorSpace']}",
                              stacklevel=3)
            identity = np.array_equal(world, np.eye(4))
            if (mesh, p) in gsz:
                if not is_glb(data):
                    raise GltfFormatError(f"{where}: gsz reads the {EXT_GSZ} payload from a .glb's BIN "
                                          "chunk only (the form gsz-encode writes)", path)
                decoded = decoded or [_decode_primitive(data, path)]     # once for every instance
                cloud, frame = decoded[0]
                if identity and frame in (FRAME_RDF, FRAME_UNSPECIFIED):
                    clouds.append(cloud)              # exactly the payload's values
                    continue
                s = to_khr(cloud, frame, name=path)
            else:
                s = _splats(doc, buffers, prim, where, path)
            clouds.append(from_khr(s if identity else transform(s, world, name=path), name=path))
    if not clouds:
        raise GltfFormatError(f"has no {KHR_GAUSSIAN_SPLATTING} primitive in its scene", path)
    if len(clouds) == 1:
        return clouds[0]
    from .layer import concat_clouds
    degree = max(c.sh_degree for c in clouds)
    return concat_clouds([c.with_sh_degree(degree) for c in clouds], degree)


def _decode_primitive(data, path):
    """(cloud, .gsz frame code) of the GLB's gsz primitive."""
    from .decode import decode
    from .glb import gsz_payload
    payload, _ = gsz_payload(data)
    frame = read_container(payload).header.frame
    return decode(bytes(data) if path is None else path), frame


def read_gltf(path) -> GaussianCloud:
    """Read the splats of a ``KHR_gaussian_splatting`` .glb or .gltf file (see
    :func:`read_gltf_bytes`); GltfFormatError naming the file when it is not one."""
    path = os.fspath(path)
    return read_gltf_bytes(read_all(path, GltfFormatError), path)


def glb_overhead(num_gaussians: int, sh_degree: int) -> int:
    """An upper bound of what :func:`gsz_glb_bytes` adds to a .gsz of at most ``num_gaussians``
    Gaussians of ``sh_degree``: its JSON, the GLB framing and padding.  The size search aims the
    .gsz at the budget less this, so that the .glb keeps the budget.  (The bound takes the longest
    JSON spelling of a float32 for the six bounding-box values -- plus 8 bytes for the minus
    signs the frame flip takes from some of them -- and ``num_gaussians`` digits for every count,
    both at least what the real file holds.)"""
    from .container import FileHeader, write_container
    worst = -1.1754943508222875e-38          # a float32 whose JSON spelling is 23 characters
    header = FileHeader(num_gaussians=max(1, int(num_gaussians)), sh_degree=int(sh_degree),
                        bbox_min=(worst,) * 3, bbox_max=(worst,) * 3)
    dummy = write_container(header, [])
    return len(gsz_glb_bytes(dummy)) - len(dummy) + 8 + 3    # + signs, + the BIN chunk's padding
