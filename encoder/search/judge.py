"""The candidate judge: every candidate is scored on the same train views with gsz-eval's
protocol (8-bit renders, per-view PSNR, plain mean); test views are never used for choices."""
from __future__ import annotations

import dataclasses

import numpy as np

from ...decoder.cloud import MADE_ROWS_STEP, MadeRows
from ...decoder.pages import trim_heap
from ...decoder.threads import for_ranges
from ...evaluation.cameras import load_cameras
from ...decoder.sh import SH_COLOUR_KLT
from ..sh_colour import coded_weights, rgb_view
from .options import SearchOptions
from .sensitivity import channel_weights

def eval_cameras(cloud, sopts: SearchOptions, cameras=None) -> list:
    """The train views candidates are compared on: ``eval_views`` of the caller's train cameras
    spread evenly over them (downscaled to ``eval_width`` where wider), or generated views at
    ``eval_width`` when there are none."""
    from ...evaluation.evaluate import pick_evenly
    if cameras:
        return [c.scaled(sopts.eval_width) if c.width > sopts.eval_width else c
                for c in pick_evenly(list(cameras), max(sopts.eval_views, 1))]
    return load_cameras(None, cloud, n_train=max(sopts.eval_views, 1), n_test=1,
                        width=sopts.eval_width).train[:sopts.eval_views]


#: A candidate's train views are rendered hardest first (lowest PSNR of the best candidate so
#: far); once at least EVAL_MIN_VIEWS of them trail the best's renders of the same views by more
#: than EVAL_DROP_MARGIN_DB on average, the candidate is dropped without rendering the rest (the
#: remaining, easier views would have to make up that deficit).  This mostly saves the renders of
#: the depth walk's losing steps.
EVAL_MIN_VIEWS = 3
EVAL_DROP_MARGIN_DB = 1.0


def view_psnr(refs, cloud, cameras, i: int) -> float:
    """PSNR of ``cloud``'s 8-bit render of view ``i`` against ``refs[i]`` (an image in [0, 1], or
    uint8 [H, W, 3]: the judge holds its references so, an eighth of their float64 form),
    rendered from a trimmed heap (a whole scene's render is a search's peak; the heap grew
    ~12 MB a view at 6 M)."""
    from ...evaluation.evaluate import render_views
    from ...evaluation.metrics import psnr
    trim_heap()
    ref = np.asarray(refs[i])
    ref = ref / 255.0 if ref.dtype == np.uint8 else ref
    return psnr(ref, render_views(cloud, [cameras[i]])[0])


def train_psnr(refs, cloud, cameras, best_views=None) -> tuple[float, list, int]:
    """(mean PSNR over the views rendered, per-view PSNRs (None where not rendered), 0 when every
    view was rendered else how many were) against ``refs`` (:func:`view_psnr`) with
    gsz-eval's protocol (8-bit renders, per-view PSNR, plain mean) -- all the search compares
    candidates by; SSIM would cost more than the renders.
    With ``best_views`` (the best candidate's per-view PSNRs) the candidate may be dropped early,
    see EVAL_DROP_MARGIN_DB."""
    if best_views is None:
        views = [view_psnr(refs, cloud, cameras, i) for i in range(len(cameras))]
        return float(np.mean(views)), views, 0
    views = [None] * len(cameras)
    diffs = []
    for i in np.argsort(np.asarray(best_views), kind="stable"):
        views[i] = view_psnr(refs, cloud, cameras, i)
        diffs.append(views[i] - best_views[i])
        if EVAL_MIN_VIEWS <= len(diffs) < len(cameras) and float(np.mean(diffs)) < -EVAL_DROP_MARGIN_DB:
            return float(np.mean([v for v in views if v is not None])), views, len(diffs)
    return float(np.mean(views)), views, 0


#: Screening stops rendering a tau's exact-attribute bound, and lets the tau through, once the
#: views rendered so far (at least SCREEN_MIN_VIEWS) beat the best candidate's renders of the
#: same views by SCREEN_PASS_MARGIN_DB on average (per-view differences: the views' own
#: difficulty, which spreads their PSNRs over 10+ dB, cancels).  A let-through tau is encoded
#: and compared as usual, and a tau that screening would skip cannot win anyway, so this only
#: trades render time against encodes; it never changes which file is chosen.
SCREEN_MIN_VIEWS = 2
SCREEN_PASS_MARGIN_DB = 1.5


def screen_psnr(refs, cloud, cameras, best_views) -> tuple[float, int]:
    """(mean PSNR over the views rendered, 0 when all were rendered, else how many): renders
    view by view and stops early when the tau clearly passes (see SCREEN_PASS_MARGIN_DB).
    The views go hardest first (lowest PSNR of the best candidate): there pruning error, which
    the bound keeps, dominates quantisation error, which it drops, so the bound is tightest."""
    order = np.argsort(np.asarray(best_views), kind="stable")
    vals, diffs = [], []
    for i in order:
        vals.append(view_psnr(refs, cloud, cameras, i))
        diffs.append(vals[-1] - best_views[i])
        if SCREEN_MIN_VIEWS <= len(vals) < len(cameras) and float(np.mean(diffs)) > SCREEN_PASS_MARGIN_DB:
            return float(np.mean(vals)), len(vals)
    return float(np.mean(vals)), 0


#: A candidate's SH rest made a row range at a time (decoder.cloud.MadeRows) is made once for all
#: its train views when it takes at most this many bytes, instead of again for every view (the
#: 1.2 M bench: 13 of 207 s); larger ones stay in ranges, so this is what a render may add to
#: the memory a search holds, whatever the scene's size.
WHOLE_SH_MAX_BYTES = 256 << 20


def rows_once(cloud):
    """``cloud`` with a row-made SH rest made whole where it takes at most WHOLE_SH_MAX_BYTES
    (the renders are the same either way)."""
    rest = cloud.sh_rest
    if not isinstance(rest, MadeRows) or rest.size * 4 > WHOLE_SH_MAX_BYTES:
        return cloud
    whole = np.empty(rest.shape, np.float32)

    def make(s: int, e: int) -> None:
        whole[s:e] = rest.rows(s, e)
    for_ranges(len(rest), MADE_ROWS_STEP, make)
    return dataclasses.replace(cloud, sh_rest=whole)


class Judge:
    """The train views, their reference renders and the channel weights of one search."""

    def __init__(self, cloud, sopts: SearchOptions, progress, cameras=None, sh_colour: int = 0):
        """``sh_colour``: the SHXF transform bits the search's clouds are coded in; every cloud
        is rendered in RGB (:func:`gsz.encoder.sh_colour.rgb_view`), as a decoder shows it."""
        from ...evaluation.metrics import to_uint8
        from ...evaluation.render import render
        self.sh_colour = sh_colour
        cloud = self.rendered(cloud)
        self.cameras = eval_cameras(cloud, sopts, cameras)
        with progress.stage("eval-reference", f"{len(self.cameras)} train views"):
            # float renders (the first two also serve as the sensitivity's base), 8-bit as
            # render_views makes them (k / 255 of these k: quantize_8bit's values)
            ref_float = [render(cloud, c).image for c in self.cameras]
            self.refs = [to_uint8(np.asarray(img)) for img in ref_float]
        self.weights = None
        if sopts.weight_channels:
            trim_heap()
            with progress.stage("sensitivity", "per-channel rendering weights of Omega"):
                # measured on the RGB view, then mixed into the coded DC channels' weights
                self.weights = coded_weights(channel_weights(cloud, self.cameras[:2], seed=sopts.seed,
                                                             base_images=ref_float[:2]), sh_colour)

    def rendered(self, cloud):
        """``cloud`` as rendered: a row-made SH rest (a candidate's decoded SH) made whole once
        for all its views (:func:`rows_once`), then seen in RGB (:func:`rgb_view`: the
        renderer turns luma/chroma colours, the field is not copied; KLT rows are made by the
        decoder's inverse, once for all views where small enough)."""
        view = rgb_view(rows_once(cloud), self.sh_colour)
        return rows_once(view) if self.sh_colour & SH_COLOUR_KLT else view

    def score(self, cloud, best_views=None) -> tuple[float, list, int]:
        """:func:`train_psnr` on this search's views."""
        return train_psnr(self.refs, self.rendered(cloud), self.cameras, best_views)

    def screen(self, cloud, best_views) -> tuple[float, int]:
        """:func:`screen_psnr` on this search's views."""
        return screen_psnr(self.refs, self.rendered(cloud), self.cameras, best_views)
