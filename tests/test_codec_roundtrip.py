"""Codec round trips on real samples: the decoder reproduces exactly what the encoder predicts,
errors stay within the quantiser's bounds, and output is deterministic."""
import numpy as np
import pytest

import gsz
from gsz.decoder import decode
from gsz.decoder.rotation import quaternion_to_matrix
from codec_util import encoded, sample


def _cov(cloud):
    r = quaternion_to_matrix(cloud.rotations.astype(np.float64))
    s = np.exp(2 * cloud.scales.astype(np.float64))
    return np.einsum("nij,nj,nkj->nik", r, s, r)


@pytest.mark.parametrize("name", ["sh0", "sh3"])
def test_decoder_reproduces_encoder_prediction_exactly(name):
    res = encoded(name, None, bits=12)
    out = decode(res.data)
    assert out.sh_degree == sample(name).sh_degree
    assert out.equals(res.cloud)


@pytest.mark.parametrize("name", ["sh0", "sh3"])
def test_12_bit_attribute_errors_are_small(name):
    """Every surviving Gaussian is close to an input Gaussian: positions within half a voxel
    diagonal, opacity/DC within a few quantiser steps of the RAHT-domain error budget."""
    src = sample(name)
    res = encoded(name, None, bits=12)
    out = res.cloud
    rep = res.report
    assert rep.voxels == len(out) <= len(src)
    assert rep.fixed.merged_fraction < 0.02
    # nearest input Gaussian of each output one (brute force is fine at this size)
    from scipy.spatial import cKDTree
    dist, nn = cKDTree(src.positions).query(out.positions)
    assert np.median(dist) < 1e-2 * np.ptp(src.positions, axis=0).max()
    matched = dist < np.percentile(dist, 90)
    # the file holds each Gaussian's nearest-identity form (its axes relabelled): the scales
    # compare as a set, the rotation through the covariance below
    assert np.abs(np.sort(out.scales, 1) - np.sort(src.scales[nn], 1))[matched].mean() < 0.01
    assert np.abs(out.opacities - src.opacities[nn])[matched].mean() < 0.05
    assert np.abs(out.sh_dc - src.sh_dc[nn])[matched].mean() < 0.02
    c_in, c_out = _cov(src.subset(nn[matched])), _cov(out.subset(np.flatnonzero(matched)))
    rel = np.linalg.norm(c_out - c_in, axis=(1, 2)) / np.linalg.norm(c_in, axis=(1, 2))
    assert np.median(rel) < 0.02


def test_more_bits_means_bigger_file_and_smaller_error():
    lo, hi = encoded("sh0", 4000, bits=6), encoded("sh0", 4000, bits=12)
    assert len(lo.data) < len(hi.data)
    src = sample("sh0", 4000)
    # same pruning/voxelisation (options differ only in bits) -> same points, same order
    assert np.array_equal(lo.cloud.positions, hi.cloud.positions)
    from scipy.spatial import cKDTree
    _, nn = cKDTree(src.positions).query(hi.cloud.positions)
    def values(cloud, f):           # scales as a set (the file relabels a Gaussian's axes)
        v = getattr(cloud, f)
        return np.sort(v, 1) if f == "scales" else v
    for f in ("opacities", "sh_dc", "scales"):
        e_lo = np.abs(values(lo.cloud, f) - values(src, f)[nn]).mean()
        e_hi = np.abs(values(hi.cloud, f) - values(src, f)[nn]).mean()
        assert e_hi < e_lo, f


def test_encoding_is_deterministic():
    from gsz.encoder.pipeline import EncodeOptions, encode
    from codec_util import FAST
    c = sample("sh3", 3000)
    a = encode(c, EncodeOptions(**FAST, bits=10)).data
    b = encode(c, EncodeOptions(**FAST, bits=10)).data
    assert a == b


def test_file_is_much_smaller_than_ply():
    res = encoded("sh3", None, bits=12)
    ply_bytes = len(gsz.decoder.ply.cloud_to_ply_bytes(sample("sh3")))
    assert len(res.data) * 5 < ply_bytes


def test_sh_keep_reproduces_kept_vectors_closely():
    res = encoded("sh3", 4000, bits=12, keep=400)
    assert res.report.sh_keep == 400
    out = decode(res.data)
    assert out.sh_rest.shape == (len(out), 15, 3)
    assert out.equals(res.cloud)


@pytest.mark.parametrize("name", ["sh0", "sh3"])
def test_default_blocks_follow_the_bit_width(name):
    """The fixed configuration's default block count: one block per channel (one quantisation
    step over all of a channel's RAHT coefficients) from 10 bits up, where it is smaller than 80
    blocks at the same width and still no larger, at least as close to the original, than 80
    blocks at 2 bits fewer (held-out views of the committed sample); 80 blocks below 10 bits,
    where one block's coarse steps round the colour detail away."""
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    from gsz.encoder.pipeline import default_blocks
    assert [default_blocks(b) for b in (4, 8, 9, 10, 12, 16)] == [80, 80, 80, 1, 1, 1]
    c = sample(name, 6000)
    cams = load_cameras(None, c, n_test=3, width=160).test
    refs = render_views(c, cams)

    def run(bits, blocks=None):
        r = encoded(name, 6000, bits=bits, blocks=blocks)
        return len(r.data), evaluate(refs, decode(r.data), cams)["psnr"], r.report.fixed.options["blocks"]
    s10, p10, k10 = run(10)
    s10_80, _, _ = run(10, 80)
    s8, p8, k8 = run(8)
    assert (k10, k8) == (1, 80)
    assert s10 < 0.9 * s10_80
    assert s10 <= 1.05 * s8 and p10 >= p8 - 0.1, (s10, p10, s8, p8)
