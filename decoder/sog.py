"""Read PlayCanvas SOG scenes: a ``.sog`` bundle (a zip of lossless WebP textures and
``meta.json``) or the unbundled ``meta.json`` beside its textures (numpy + Pillow with WebP,
imported only here: the ``formats`` extra).

Texel i of every texture belongs to Gaussian i (row-major).  Version 2 (``"version": 2``):
``means_l``/``means_u`` hold 16-bit positions in a ``sign(x) ln(|x| + 1)`` warp between the
meta's mins and maxs; ``quats`` the smallest three of the unit quaternion (bytes over
+-1/sqrt 2) and, in alpha, 252 + the index (w, x, y, z) of the one left out; ``scales`` and the
RGB of ``sh0`` index 256-entry codebooks (log-scales; SH DC), ``sh0``'s alpha is the alpha byte;
``shN`` (optional) gives each Gaussian a 16-bit label into a palette of SH vectors, each
coefficient an RGB texel of codebook indices.  Version 1 (no ``version`` key) stores per-axis
mins and maxs instead of codebooks, and the opacity logit in ``sh0``'s alpha.  PLY (RDF) frame,
as splat-transform writes it.
"""
from __future__ import annotations

import io
import json
import os
import posixpath
import zipfile

import numpy as np

from .cloud import GaussianCloud
from .delivery import logit_of_alpha_bytes, smallest_three, unit_quaternions
from .io_util import read_all
from .errors import MissingExtraError, SogFormatError
from .io_util import check_input_file

#: meta.json larger than this is no SOG meta (it holds three 256-entry codebooks)
MAX_META_BYTES = 16 << 20
_SH_COEFFS = {0: 0, 1: 3, 2: 8, 3: 15}
#: a v1 meta says its SH bands by the width of the centroid texture only
_V1_BANDS_BY_WIDTH = {192: 1, 512: 2, 960: 3}


def is_sog_meta(doc) -> bool:
    """True for a parsed JSON document that is a SOG meta.json (not, say, a glTF)."""
    return isinstance(doc, dict) and isinstance(doc.get("means"), dict) and "quats" in doc


def is_sog_zip(head: bytes) -> bool:
    """True for the first bytes of a zip archive (a .sog bundle is a zip holding meta.json)."""
    return head[:4] == b"PK\x03\x04"


def read_sog(path) -> GaussianCloud:
    """The scene in the SOG bundle or meta.json at ``path`` as a graphdeco cloud.
    :class:`SogFormatError` names the file (and the texture) and the problem;
    :class:`MissingExtraError` says to install ``gsz[formats]`` when Pillow is missing."""
    path = os.fspath(path)
    data = read_all(path, SogFormatError)
    if is_sog_zip(data):
        return _read_bundle(data, path)
    try:
        meta = json.loads(data.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError) as e:
        raise SogFormatError(f"not a SOG meta.json: not valid JSON ({e})", path) from None
    folder = os.path.dirname(os.path.abspath(path))

    def load(name):
        rel = _texture_name(name, path)
        full = os.path.join(folder, *rel.split("/"))

        def beside(message, _where=None):        # the problem of a texture, named from meta.json
            return SogFormatError(f"its texture {rel}: {message}", path)
        check_input_file(full, beside)
        return read_all(full, beside)

    return _decode(meta, load, path)


def _read_bundle(data: bytes, path: str) -> GaussianCloud:
    try:
        z = zipfile.ZipFile(io.BytesIO(data))
        names = {i.filename: i for i in z.infolist()}
    except (zipfile.BadZipFile, ValueError, EOFError) as e:
        raise SogFormatError(f"not a readable .sog bundle (zip): {e}", path) from None
    if "meta.json" not in names:
        raise SogFormatError("is a zip archive without meta.json: not a .sog bundle", path)

    def load(name):
        info = names.get(_texture_name(name, path))
        if info is None:
            raise SogFormatError(f"its meta.json names {name!r}, which the bundle does not hold", path)
        if info.file_size > max(len(data) * 64, 64 << 20):
            raise SogFormatError(f"{name} declares {info.file_size:,} bytes: corrupt, or a zip bomb", path)
        try:
            return z.read(info)
        except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, OSError, NotImplementedError) as e:
            raise SogFormatError(f"cannot read {name} from the bundle (truncated?): {e}", path) from None

    raw = load("meta.json")
    if len(raw) > MAX_META_BYTES:
        raise SogFormatError(f"its meta.json is {len(raw):,} bytes: not a SOG meta", path)
    try:
        meta = json.loads(raw.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError) as e:
        raise SogFormatError(f"its meta.json is not valid JSON: {e}", path) from None
    return _decode(meta, load, path)


def _texture_name(name, path) -> str:
    """``name`` as a relative path inside the bundle or beside meta.json; refuses names that
    climb out of it."""
    if not isinstance(name, str) or not name:
        raise SogFormatError(f"its meta.json names a texture {name!r} that is not a file name", path)
    norm = posixpath.normpath(name.replace("\\", "/"))
    if norm.startswith(("/", "../")) or norm == ".." or ":" in norm.split("/")[0]:
        raise SogFormatError(f"its meta.json names {name!r}, outside the scene's folder", path)
    return norm


def _pillow(path):
    try:
        from PIL import Image, features
    except ImportError:
        raise MissingExtraError("reading a PlayCanvas SOG scene needs Pillow with WebP support: "
                                "pip install 'gsz[formats]'", path) from None
    if not features.check("webp"):
        raise MissingExtraError("reading a PlayCanvas SOG scene needs Pillow built with WebP support "
                                "(pip install --force-reinstall pillow)", path)
    return Image


def _texture(load, name, path, Image, min_texels: int, max_texels: int):
    """([H*W, 4] uint8 RGBA texels, W) of the WebP ``name``; its size checked before decoding."""
    raw = load(name)
    limit = Image.MAX_IMAGE_PIXELS
    try:
        # our own bound replaces Pillow's bomb guard, which would refuse a real ~100 M-Gaussian scene
        Image.MAX_IMAGE_PIXELS = max(max_texels, limit or 0) + 1
        im = Image.open(io.BytesIO(raw))
        w, h = im.size
        if im.format != "WEBP":
            raise SogFormatError(f"texture {name} is a {im.format} image, not a WebP", path)
        if not min_texels <= w * h <= max_texels:
            raise SogFormatError(f"texture {name} is {w}x{h}: {w * h:,} texels where {min_texels:,}"
                                 f"-{max_texels:,} are expected", path)
        rgba = np.asarray(im.convert("RGBA"), np.uint8)
    except SogFormatError:
        raise
    except Exception as e:          # Pillow raises many types for a damaged image
        raise SogFormatError(f"texture {name} is not a readable WebP: {e}", path) from None
    finally:
        Image.MAX_IMAGE_PIXELS = limit
    return rgba.reshape(-1, 4), w


def _meta_fail(path, what):
    return SogFormatError(f"its meta.json is not a SOG meta: {what}", path)


def _floats(meta, key, sub, n, path):
    try:
        v = np.asarray(meta[key][sub], np.float64).reshape(-1)
    except (KeyError, TypeError, ValueError):
        raise _meta_fail(path, f"missing or malformed {key}.{sub}") from None
    if (n is not None and v.size != n) or not np.isfinite(v).all():
        raise _meta_fail(path, f"{key}.{sub} should be {n} finite numbers")
    return v


def _files(meta, key, count, path):
    try:
        files = list(meta[key]["files"])
    except (KeyError, TypeError):
        raise _meta_fail(path, f"missing {key}.files") from None
    if len(files) < count:
        raise _meta_fail(path, f"{key}.files names {len(files)} textures, not {count}")
    return files


def _decode(meta, load, path) -> GaussianCloud:
    if not is_sog_meta(meta):
        raise _meta_fail(path, "no means/quats entries")
    version = meta.get("version")
    if version not in (None, 2):
        raise SogFormatError(f"SOG version {version!r} is not one gsz reads (1 or 2)", path)
    Image = _pillow(path)
    try:
        n = int(meta["count"]) if version == 2 else int(meta["means"]["shape"][0])
    except (KeyError, TypeError, ValueError, IndexError):
        raise _meta_fail(path, "no Gaussian count (count, or means.shape)") from None
    if not 0 < n <= 1 << 28:
        raise _meta_fail(path, f"a Gaussian count of {n:,}")
    cap = 2 * n + (1 << 16)              # textures are about sqrt(n) square, padded

    def tex(key, i=0):
        return _texture(load, _files(meta, key, i + 1, path)[i], path, Image, n, cap)[0][:n]

    lo, hi = tex("means", 0), tex("means", 1)
    mins, maxs = _floats(meta, "means", "mins", 3, path), _floats(meta, "means", "maxs", 3, path)
    span = np.where(maxs - mins == 0, 1.0, maxs - mins)
    u = (lo[:, :3].astype(np.float64) + 256.0 * hi[:, :3]) / 65535.0
    warped = mins + span * u
    positions = np.sign(warped) * np.expm1(np.abs(warped))         # inverse of sign(x) ln(|x| + 1)

    q = tex("quats")
    tag = q[:, 3].astype(np.int64)
    bad = (tag < 252) | (tag > 255)
    if bad.any():
        raise SogFormatError(f"texture {_files(meta, 'quats', 1, path)[0]}: {int(bad.sum()):,} Gaussians "
                             f"have a quaternion tag outside 252-255 (first at {int(np.argmax(bad))})", path)
    abc = (q[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / np.sqrt(2.0)
    rotations = unit_quaternions(smallest_three(tag - 252, abc[:, 0], abc[:, 1], abc[:, 2]))

    sc, c0 = tex("scales"), tex("sh0")
    if version == 2:
        scale_book = _floats(meta, "scales", "codebook", 256, path)
        dc_book = _floats(meta, "sh0", "codebook", 256, path)
        scales = scale_book[sc[:, :3]]
        sh_dc = dc_book[c0[:, :3]]
        opacities = logit_of_alpha_bytes(c0[:, 3])
    else:
        smin, smax = _floats(meta, "scales", "mins", 3, path), _floats(meta, "scales", "maxs", 3, path)
        scales = smin + (smax - smin) * (sc[:, :3] / 255.0)
        cmin, cmax = _floats(meta, "sh0", "mins", 4, path), _floats(meta, "sh0", "maxs", 4, path)
        lerp = cmin + (cmax - cmin) * (c0 / 255.0)
        sh_dc, opacities = lerp[:, :3], lerp[:, 3].astype(np.float32)   # v1 stores the logit itself

    degree, rest = 0, np.zeros((n, 0, 3), np.float32)
    if meta.get("shN"):
        degree, rest = _sh_rest(meta, load, path, Image, n, cap, version)
    return GaussianCloud(positions.astype(np.float32), scales.astype(np.float32), rotations, opacities,
                         sh_dc.astype(np.float32), rest, degree)


def _sh_rest(meta, load, path, Image, n, cap, version):
    files = _files(meta, "shN", 2, path)
    labels = _texture(load, files[1], path, Image, n, cap)[0][:n]
    if version == 2:
        try:
            bands, count = int(meta["shN"]["bands"]), int(meta["shN"]["count"])
        except (KeyError, TypeError, ValueError):
            raise _meta_fail(path, "shN without bands and count") from None
        if bands not in (1, 2, 3):
            raise _meta_fail(path, f"shN.bands is {bands}, not 1-3")
        coeffs = _SH_COEFFS[bands]
        book = _floats(meta, "shN", "codebook", 256, path)
        centroids, width = _texture(load, files[0], path, Image, 1, 64 * coeffs * ((count + 63) // 64))
        if width != 64 * coeffs:
            raise SogFormatError(f"texture {files[0]} is {width} texels wide; a {bands}-band SH palette "
                                 f"is {64 * coeffs}", path)
    else:
        centroids, width = _texture(load, files[0], path, Image, 1, 960 * 1024)
        bands = _V1_BANDS_BY_WIDTH.get(width)
        if bands is None:
            raise SogFormatError(f"texture {files[0]} is {width} texels wide; a v1 SH palette is 192, 512 "
                                 "or 960", path)
        coeffs = _SH_COEFFS[bands]
        count = centroids.shape[0] // coeffs
        lo_v, hi_v = _floats(meta, "shN", "mins", 1, path)[0], _floats(meta, "shN", "maxs", 1, path)[0]
        book = lo_v + (hi_v - lo_v) * (np.arange(256) / 255.0)
    label = labels[:, 0].astype(np.int64) | (labels[:, 1].astype(np.int64) << 8)
    rows = centroids.shape[0] // width
    bad = (label >= count) | (label >= rows * 64)
    if bad.any():
        raise SogFormatError(f"texture {files[1]}: {int(bad.sum()):,} Gaussians point past the "
                             f"{count:,}-entry SH palette (first at {int(np.argmax(bad))})", path)
    # entry e sits in row e // 64, columns (e % 64) * coeffs .. + coeffs, one texel per coefficient
    texel = ((label // 64) * width + (label % 64) * coeffs)[:, None] + np.arange(coeffs)[None, :]
    rest = book[centroids[texel, :3]]                                   # [N, coeffs, RGB]
    return bands, rest.astype(np.float32)
