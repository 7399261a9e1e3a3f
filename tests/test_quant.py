"""Group-wise min-max quantisation: normative dequantiser, CPU kernels vs a naive reference."""
import numpy as np
import pytest
import torch

from gsz.decoder.errors import GszError, GszFormatError
from gsz.decoder.morton import morton_encode
from gsz.decoder.quant import dequantize_groups, split_lengths, step_sizes
from gsz.decoder.raht import build_raht_tree
from gsz.decoder.rotation import quaternion_to_euler
from gsz.encoder.raht import raht_forward
from gsz.kernels.quantize import quantize_all_bits, quantize_groups


@pytest.fixture(scope="module")
def real_channels(sample_sh0):
    """[10, N-1] float32: 7 RAHT AC channels + 3 log-scale channels of a real scene."""
    c = sample_sh0
    p = c.positions.astype(np.float64)
    ijk = np.minimum(((p - p.min(0)) / (p.max(0) - p.min(0)) * 2 ** 12).astype(np.int64), 4095)
    codes, first, inv = np.unique(morton_encode(ijk), return_index=True, return_inverse=True)
    attrs = np.concatenate([c.opacities[:, None], quaternion_to_euler(c.rotations), c.sh_dc], 1)
    sums = np.zeros((codes.size, 7))
    np.add.at(sums, inv, attrs)
    _, ac = raht_forward(sums / np.bincount(inv)[:, None], build_raht_tree(codes, 12))
    scales = c.scales[first][1:]          # one per voxel, length N-1 to stack with the AC rows
    return np.ascontiguousarray(np.concatenate([ac.T, scales.T]).astype(np.float32))


def naive(x, num_blocks, bits_per_group=None):
    """Loop-per-group float64 numpy reference of the normative quantiser."""
    c, length = x.shape
    lens = split_lengths(length, num_blocks)
    starts = np.concatenate([[0], np.cumsum(lens)])
    mins = np.zeros((c, num_blocks), np.float32)
    maxs = np.zeros((c, num_blocks), np.float32)
    loss = np.zeros((c, num_blocks, 16))
    sym = np.zeros((c, length), np.int64)
    for ci in range(c):
        for b in range(num_blocks):
            seg = x[ci, starts[b]:starts[b + 1]].astype(np.float64)
            if seg.size == 0:
                continue
            m, big = np.float32(seg.min()), np.float32(seg.max())
            mins[ci, b], maxs[ci, b] = m, big
            for q in range(1, 17):
                levels = 2.0 ** q - 1
                s = (float(big) - float(m)) / levels if big > m else 1.0
                k = np.clip(np.rint((seg - float(m)) / s), 0, levels)
                loss[ci, b, q - 1] = np.sum((seg - (float(m) + s * k)) ** 2)
                if bits_per_group is not None and bits_per_group[ci, b] == q:
                    sym[ci, starts[b]:starts[b + 1]] = k
    return mins, maxs, loss, sym


def test_split_lengths():
    assert split_lengths(10, 3).tolist() == [4, 3, 3]
    assert split_lengths(9, 3).tolist() == [3, 3, 3]
    assert split_lengths(2, 4).tolist() == [1, 1, 0, 0]
    assert split_lengths(542_000, 80).sum() == 542_000
    with pytest.raises(GszFormatError):
        split_lengths(5, 0)


def test_step_sizes_formula():
    s = step_sizes(np.array([0.0, 1.0, -2.0], np.float32), np.array([3.0, 1.0, 2.0], np.float32),
                   np.array([2, 5, 16]))
    assert np.array_equal(s, [1.0, 1.0, 4.0 / 65535])
    # Uses the float32-rounded stored values, not a float64 the encoder might hold.
    assert step_sizes(np.float64(0.1), np.float64(1.1), 1) == float(np.float32(1.1)) - float(np.float32(0.1))


def test_loss_table_and_symbols_match_naive_reference(real_channels):
    x = real_channels[:, :6003]                         # 6003 = not a multiple of the block count
    rng = np.random.default_rng(5)
    bits = rng.integers(1, 17, (x.shape[0], 13))
    mins_ref, maxs_ref, loss_ref, sym_ref = naive(x, 13, bits)
    fn, mins, maxs, loss = quantize_all_bits(torch.from_numpy(np.ascontiguousarray(x)), 13, device="cpu")
    assert np.array_equal(mins, mins_ref) and np.array_equal(maxs, maxs_ref)
    assert loss.shape == (10, 13, 16) and loss.dtype == np.float64
    assert np.allclose(loss, loss_ref, rtol=1e-9, atol=1e-300)
    assert np.array_equal(fn(bits), sym_ref)
    sym2, mins2, maxs2 = quantize_groups(x, 13, bits, device="cpu")
    assert np.array_equal(sym2, sym_ref) and np.array_equal(mins2, mins) and sym2.dtype == np.int32
    # The decoder's dequantisation reproduces exactly the error the loss table promised.
    xh = dequantize_groups(sym2, mins2, maxs2, bits, split_lengths(x.shape[1], 13))
    starts = np.concatenate([[0], np.cumsum(split_lengths(x.shape[1], 13))[:-1]])
    err = np.add.reduceat((x.astype(np.float64) - xh) ** 2, starts, axis=1)
    chosen = np.take_along_axis(loss, bits[..., None] - 1, 2)[..., 0]
    assert np.allclose(err, chosen, rtol=1e-9, atol=1e-300)
    # Each value is within half a step of its reconstruction.
    s = np.repeat(step_sizes(mins2, maxs2, bits), split_lengths(x.shape[1], 13), axis=1)
    assert np.all(np.abs(x - xh) <= 0.5 * s * (1 + 1e-9))


def test_loss_monotone_and_full_size_real_data(real_channels):
    _, mins, maxs, loss = quantize_all_bits(real_channels, 80)
    assert np.all(np.isfinite(loss)) and np.all(loss >= 0)
    # The q and q+1 grids are not nested (2^q - 1 vs 2^(q+1) - 1 steps), so a group's loss may
    # rise with q on lattice-like data (this sample's colours came through an 8-bit format): rare.
    rises = np.diff(loss, axis=2) > 0
    assert rises.mean() < 0.005
    assert np.all(np.diff(loss.sum(axis=(0, 1))) < 0)       # the channel-set total always falls
    # Hard bound: every element is within half a step, so loss <= n * s^2 / 4.
    n = split_lengths(real_channels.shape[1], 80)[None, :, None]
    s = step_sizes(mins[..., None], maxs[..., None], np.arange(1, 17)[None, None, :])
    assert np.all(loss <= n * s ** 2 / 4 * (1 + 1e-9))
    # Halving the step cuts the error roughly by 4 in the fine regime.
    ratio = loss[..., 10].sum() / loss[..., 11].sum()
    assert 3.0 < ratio < 5.0


def test_bit_range_and_determinism(real_channels):
    _, _, _, a = quantize_all_bits(real_channels, 20, bit_range=(3, 9))
    _, _, _, b = quantize_all_bits(real_channels, 20, bit_range=(3, 9))
    assert np.array_equal(a, b)
    assert np.all(np.isinf(a[..., :2])) and np.all(np.isinf(a[..., 9:]))
    assert np.all(np.isfinite(a[..., 2:9]))


def test_empty_blocks_and_constant_groups():
    x = np.array([[1.0, 1.0, 1.0], [0.0, 2.0, -1.0]], np.float32)
    fn, mins, maxs, loss = quantize_all_bits(x, 5)        # blocks of 1,1,1,0,0
    assert np.array_equal(loss, np.zeros((2, 5, 16)))
    bits = np.full((2, 5), 4)
    sym = fn(bits)
    assert np.array_equal(sym, np.zeros((2, 3)))          # single-element groups: k = 0, x_hat = m
    xh = dequantize_groups(sym, mins, maxs, bits, split_lengths(3, 5))
    assert np.array_equal(xh, x.astype(np.float64))


def test_bad_input_raises_gsz_errors():
    for bad in (np.nan, np.inf, -np.inf):
        x = np.ones((2, 10), np.float32)
        x[1, 3] = bad
        with pytest.raises(GszError, match="NaN or infinity"):
            quantize_all_bits(x, 2)
        with pytest.raises(GszError, match="NaN or infinity"):
            quantize_groups(x, 2, 4)
    big = np.ones((2, 10))
    big[0, 9] = 1e300                                   # finite in float64, infinite in float32
    with pytest.raises(GszError, match="NaN or infinity"):
        quantize_groups(big, 2, 4)
    with pytest.raises(GszError):
        quantize_groups(np.ones((2, 10), np.float32), 2, np.full((2, 2), 17))
    with pytest.raises(GszError):
        quantize_all_bits(np.ones(10, np.float32), 2)
    with pytest.raises(GszError):
        quantize_all_bits(np.ones((2, 10), np.float32), 2, bit_range=(0, 16))
    mins = np.zeros((1, 2), np.float32)
    maxs = np.ones((1, 2), np.float32)
    lens = split_lengths(4, 2)
    with pytest.raises(GszFormatError, match="exceeds"):
        dequantize_groups(np.array([[0, 4, 0, 1]]), mins, maxs, np.array([[2, 2]]), lens)
    with pytest.raises(GszFormatError, match="max < min"):
        dequantize_groups(np.zeros((1, 4), int), maxs, mins, np.array([[2, 2]]), lens)
    with pytest.raises(GszFormatError):
        dequantize_groups(np.zeros((1, 5), int), mins, maxs, np.array([[2, 2]]), lens)
    with pytest.raises(GszFormatError):
        dequantize_groups(np.zeros((1, 4), int), mins, maxs, np.array([[0, 2]]), lens)
    with pytest.raises(GszFormatError):
        dequantize_groups(np.zeros((1, 4), int), np.array([[0, np.inf]], np.float32), maxs,
                          np.array([[2, 2]]), lens)


def test_channel_set_float32_reconstruction_is_the_decoders_values_rounded():
    """The SH writer keeps its reconstruction float32 (half the memory), or none: the same
    bytes, and the decoder's float64 values rounded, constant groups included."""
    from gsz.decoder.bytesio import Reader
    from gsz.decoder.groups import read_channel_set
    from gsz.encoder.groups import write_channel_set
    rng = np.random.default_rng(3)
    x = (rng.standard_normal((19, 5000)) * 0.1).astype(np.float32)
    bits = rng.integers(0, 10, size=(19, 8))
    data64, rec64 = write_channel_set(x, bits, 8)
    data32, rec32 = write_channel_set(x, bits, 8, recon_dtype=np.float32)
    assert data32 == data64 and rec32.dtype == np.float32
    # bytes only: the symbols made a few channels at a time (19 channels: 3 chunks, the last short)
    only, none = write_channel_set(x, bits, 8, recon_dtype=None)
    assert only == data64 and none is None
    decoded = read_channel_set(Reader(data32), max_length=5000)
    np.testing.assert_array_equal(rec64, decoded)
    np.testing.assert_array_equal(rec32, decoded.astype(np.float32))


@pytest.mark.skipif(not __import__("gsz.decoder.native", fromlist=["enabled"]).enabled(),
                    reason="native accelerator not built")
@pytest.mark.parametrize("length, blocks, bit_range", [(20000, 8, (1, 16)), (5, 8, (1, 16)),
                                                        (3001, 7, (3, 9))])
def test_loss_table_in_c_matches_the_torch_reference(length, blocks, bit_range):
    """The loss table the allocation reads comes from C where the accelerator is built: the
    torch reference's values to float64 rounding, +inf outside the range, 0 for empty groups."""
    from gsz.kernels import quantize_cpu
    rng = np.random.default_rng(length)
    x = (rng.standard_normal((5, length)) * 0.1).astype(np.float32)
    x[2] = 0.25                                          # a constant channel: step 1
    _, mins, maxs, loss = quantize_all_bits(x, blocks, bit_range)
    t = torch.from_numpy(x)
    ref = quantize_cpu.loss_all_bits(t, blocks, torch.from_numpy(mins), torch.from_numpy(maxs),
                                     *bit_range).numpy()
    assert np.array_equal(np.isinf(loss), np.isinf(ref))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(loss[fin], ref[fin], rtol=1e-12, atol=1e-300)
    assert np.all(loss[2][fin[2]] == 0.0) and np.all(loss[:, :, :bit_range[0] - 1] == np.inf)


@pytest.mark.skipif(not __import__("gsz.decoder.native", fromlist=["enabled"]).enabled(),
                    reason="native accelerator not built")
def test_symbols_in_c_equal_the_torch_reference_bit_for_bit():
    """quantize_groups runs in C where the accelerator is built: the normative symbols, ties
    (values exactly half a step between two levels) rounded to even like the reference."""
    from gsz.kernels import quantize_cpu
    rng = np.random.default_rng(11)
    x = (rng.standard_normal((6, 9001)) * 0.1).astype(np.float32)
    # channel 0 on exact half steps: step 2^-4 at 4 bits (min 0, max 15/16)
    x[0] = (rng.integers(0, 15, 9001) + 0.5) / 16.0
    starts = np.concatenate([[0], np.cumsum(split_lengths(9001, 5))[:-1]])
    x[0, starts], x[0, starts + 1] = 0.0, 15.0 / 16.0    # every block's min and max
    x[1] = 0.3                                           # constant: step 1, every symbol 0
    bits = rng.integers(1, 17, size=(6, 5))
    bits[0] = 4
    sym, mins, maxs = quantize_groups(x, 5, bits)
    ref = quantize_cpu.quantize(torch.from_numpy(x), 5, torch.from_numpy(bits),
                                torch.from_numpy(mins), torch.from_numpy(maxs)).numpy()
    assert sym.dtype == np.int32 and np.array_equal(sym, ref)
    assert np.all(sym[1] == 0)
    assert np.array_equal(sym[0], np.rint(x[0] * 16.0).astype(np.int32))   # ties to even


@pytest.mark.skipif(not __import__("gsz.decoder.native", fromlist=["enabled"]).enabled(),
                    reason="native accelerator not built")
def test_c_quantiser_refuses_arrays_that_do_not_fit_together():
    from gsz.decoder import native
    mod = native.module()
    x = np.zeros((3, 10), np.float32)
    mm = np.zeros((3, 2), np.float32)
    bits = np.full((3, 2), 4, np.int64)
    with pytest.raises(ValueError, match="inconsistent"):
        mod.quantize_groups(x, 2, mm, mm[:2], bits, np.empty((3, 10), np.int32))   # maxs short
    with pytest.raises(ValueError, match="inconsistent"):
        mod.quantize_groups(x, 2, mm, mm, np.full((3, 2), 17, np.int64), np.empty((3, 10), np.int32))
    with pytest.raises(ValueError, match="inconsistent"):
        mod.loss_all_bits(x, 2, mm, mm, 3, 2, np.zeros((3, 2, 16)))                # lo > hi
