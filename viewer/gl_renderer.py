"""OpenGL (moderngl) splat renderer with the CPU reference renderer's semantics.

Pipeline per frame, for one :class:`~gsz.decoder.cloud.GaussianCloud` and one
:class:`~gsz.evaluation.cameras.Camera`:

1. **Preprocess** (compute shader ``shaders/preprocess.comp.glsl``, one invocation per splat):
   near-plane cull (view depth <= 0.2), 3D covariance from the normalised quaternion and
   ``exp(log_scale) * scale_modifier``, EWA projection with graphdeco's clamped Jacobian and
   0.3 px dilation, conic, radius ``ceil(3 sqrt(lambda_max))`` and the graphdeco tile
   rectangle, view-dependent SH colour up to degree 3 (``max(SH + 0.5, 0)``).  The same maths
   as :mod:`gsz.evaluation.render`, so a GL frame matches the CPU reference (tests: >= 30 dB,
   measured 83 to 100 dB after 8-bit rounding on tests/data and the 542k flowers scene).
2. **Sort**: indices of the splats in front of the near plane, back to front by view-space
   depth ``z`` (the reference's key, formed like it: float64 then float32), on the CPU with
   numpy; :func:`depth_order` reverses a *stable* ascending sort so equal depths composite
   exactly like the reference's stable front-to-back order.  The interactive app runs this
   on a worker thread (:mod:`gsz.viewer.sorter`).
3. **Draw**: one instanced triangle-strip quad per splat: the oriented bounding rectangle of
   its ``alpha >= 1/255`` ellipse (or its pixel box when smaller), chosen in the compute pass;
   the fragment shader drops pixels outside the graphdeco tile rectangle (the reference never
   composites a splat there), computes ``alpha = min(0.99, opacity * exp(power))``, discards
   ``power > 0`` and ``alpha < 1/255`` and writes premultiplied ``(colour * alpha, alpha)``.  Blending ``ONE, ONE_MINUS_SRC_ALPHA``
   back to front over a target cleared to the background yields the reference's
   ``sum c_i a_i T_i + T * background`` (alpha channel: 1 - T).  The one difference: the
   reference stops a pixel once ``T < 1e-4``; blending cannot, so the splats behind such a
   pixel add at most 1e-4 of their colour.
   The target is an RGBA32F texture: an 8-bit target would round after every blend.

Buffers: splat parameters (64 B/splat) and SH coefficients (up to 180 B/splat at degree 3)
live in SSBOs; because ``GL_MAX_SHADER_STORAGE_BLOCK_SIZE`` may be as small as 128 MiB
(llvmpipe), the preprocess pass is dispatched in chunks, each binding a range of the buffers
that fits (a 1M-splat degree-3 scene needs two chunks).  The projected buffer (64 B/splat)
must fit one binding: 2.1M splats at 128 MiB, far more on real GPUs (NVIDIA: 2 GiB+).
"""
from __future__ import annotations

import os
import time
from importlib import resources

import numpy as np

from ..decoder.cloud import GaussianCloud
from ..decoder.errors import GszError

__all__ = ["GLUnavailable", "create_headless_context", "load_shader", "depth_order",
           "SplatRenderer", "FloatTarget", "render_image"]

NEAR = 0.2
_WORKGROUP = 256
#: chunk sizes are multiples of this (keeps SSBO range offsets aligned for any GL driver)
_CHUNK_ALIGN = 1024
_PROJECTED_BYTES = 64


class GLUnavailable(GszError):
    """No OpenGL 4.3 context could be created (no driver, no EGL, ...)."""


def create_headless_context():
    """A standalone OpenGL 4.3+ context through EGL (no display needed; Mesa llvmpipe on CPU).

    Raises :class:`GLUnavailable` with the driver's message when none can be created.
    """
    try:
        import moderngl
    except ImportError as e:
        raise GLUnavailable(f"moderngl is not installed ({e}); pip install 'gsz[viewer]'") from None
    errors = []
    for kwargs in ({"backend": "egl"}, {}):
        try:
            return moderngl.create_standalone_context(require=430, **kwargs)
        except Exception as e:  # moderngl raises bare Exception for driver failures
            errors.append(f"{kwargs.get('backend', 'default')}: {str(e).strip() or type(e).__name__}")
    raise GLUnavailable("cannot create an OpenGL 4.3 context (" + "; ".join(errors) + ")")


def load_shader(name: str) -> str:
    """Source of ``viewer/shaders/<name>`` (shipped as package data)."""
    try:
        return resources.files("gsz.viewer").joinpath("shaders", name).read_text()
    except (ModuleNotFoundError, FileNotFoundError, TypeError):
        here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "shaders", name)
        with open(here) as f:
            return f.read()


def view_depth(positions: np.ndarray, camera) -> np.ndarray:
    """[N] float32 view-space depth ``z`` of ``positions`` [N, 3] (float64 maths, like the
    reference renderer, then float32 -- the reference's sort key)."""
    z = positions.astype(np.float64) @ camera.R[2].astype(np.float64)
    return (z + camera.t[2]).astype(np.float32)


def depth_order(positions: np.ndarray, camera, near: float = NEAR) -> np.ndarray:
    """[M] uint32 indices of the splats with view depth > ``near``, BACK TO FRONT.

    The reference composites front to back in increasing depth with ties in index order (a
    stable sort); reversing a stable ascending sort gives exactly the back-to-front order
    that blends to the same result.  ~12 ms per 100k splats (numpy argsort, one core).
    """
    z = view_depth(positions, camera)
    vis = np.flatnonzero(z > near)
    order = vis[np.argsort(z[vis], kind="stable")[::-1]]
    return order.astype(np.uint32)


class FloatTarget:
    """An RGBA32F colour texture + framebuffer of a given size (the splats' render target)."""

    def __init__(self, ctx, width: int, height: int):
        self.ctx = ctx
        self.width, self.height = int(width), int(height)
        self.texture = ctx.texture((self.width, self.height), 4, dtype="f4")
        self.texture.filter = (ctx.NEAREST if hasattr(ctx, "NEAREST") else 0x2600,) * 2
        self.fbo = ctx.framebuffer(color_attachments=[self.texture])

    @property
    def size(self):
        return self.width, self.height

    def read(self) -> np.ndarray:
        """[H, W, 4] float32, row 0 = top of the image (premultiplied colour + alpha)."""
        raw = self.fbo.read(components=4, dtype="f4")
        return np.frombuffer(raw, np.float32).reshape(self.height, self.width, 4)[::-1].copy()

    def release(self):
        self.fbo.release()
        self.texture.release()


class SplatRenderer:
    """GPU buffers and programs of one cloud in one moderngl context.

    ``render(camera, target, order=...)`` draws the cloud from ``camera`` into ``target`` (a
    :class:`FloatTarget` whose size must equal the camera's image size).  Not thread-safe: use
    it from the thread that owns the GL context.
    """

    def __init__(self, ctx, cloud: GaussianCloud):
        import moderngl
        if not isinstance(cloud, GaussianCloud):
            raise GszError(f"SplatRenderer: expected a GaussianCloud, got {type(cloud).__name__}")
        self.ctx = ctx
        self.cloud = cloud
        self.n = len(cloud)
        self.sh_degree = int(cloud.sh_degree)
        self.k = (self.sh_degree + 1) ** 2 - 1
        limit = int(ctx.info.get("GL_MAX_SHADER_STORAGE_BLOCK_SIZE", 1 << 27))
        if self.n * _PROJECTED_BYTES > limit:
            raise GszError(f"scene has {self.n} splats; this GL driver's largest storage block "
                           f"({limit >> 20} MiB) holds at most {limit // _PROJECTED_BYTES} "
                           "projected splats")
        # Chunk size: splats whose parameter and SH ranges both fit one storage block.
        per_splat = max(64, self.k * 3 * 4)
        chunk = max(_CHUNK_ALIGN, (limit // per_splat) // _CHUNK_ALIGN * _CHUNK_ALIGN)
        self.chunk = chunk

        params = np.zeros((self.n, 16), np.float32)
        params[:, 0:3] = cloud.positions
        params[:, 3] = cloud.opacities
        params[:, 4:7] = cloud.scales
        params[:, 8:12] = cloud.rotations
        params[:, 12:15] = cloud.sh_dc
        n_alloc = max(self.n, 1)
        self.params = ctx.buffer(params.tobytes() if self.n else bytes(64))
        if self.k:
            self.sh = ctx.buffer(np.ascontiguousarray(cloud.sh_rest[:, :self.k], np.float32).tobytes())
        else:
            self.sh = ctx.buffer(reserve=16)
        self.projected = ctx.buffer(reserve=n_alloc * _PROJECTED_BYTES)
        self.order_buf = ctx.buffer(reserve=n_alloc * 4)
        self.prep = ctx.compute_shader(load_shader("preprocess.comp.glsl"))
        self.prog = ctx.program(vertex_shader=load_shader("splat.vert.glsl"),
                                fragment_shader=load_shader("splat.frag.glsl"))
        self.vao = ctx.vertex_array(self.prog, [])
        self._moderngl = moderngl
        self.last_times = {"preprocess_s": 0.0, "draw_s": 0.0}

    def release(self):
        for obj in (self.vao, self.prog, self.prep, self.params, self.sh, self.projected,
                    self.order_buf):
            obj.release()

    # -------------------------------------------------------------------------------------------
    def preprocess(self, camera, *, sh_degree: int | None = None, scale_modifier: float = 1.0):
        """Run the compute pass for ``camera`` (fills the projected buffer)."""
        deg = self.sh_degree if sh_degree is None else int(sh_degree)
        if not 0 <= deg <= self.sh_degree:
            raise GszError(f"sh_degree must be in 0..{self.sh_degree} for this scene, got {sh_degree}")
        if not (np.isfinite(scale_modifier) and scale_modifier > 0):
            raise GszError(f"scale_modifier must be positive, got {scale_modifier}")
        p = self.prep
        p["u_k"].value = self.k
        p["u_degree"].value = deg
        p["u_R"].write(np.ascontiguousarray(camera.R.T, np.float32).tobytes())
        p["u_t"].value = tuple(float(v) for v in camera.t)
        p["u_campos"].value = tuple(float(v) for v in camera.center)
        p["u_intr"].value = (camera.fx, camera.fy, camera.cx - 0.5, camera.cy - 0.5)
        p["u_size"].value = (float(camera.width), float(camera.height))
        p["u_scale_mod"].value = float(scale_modifier)
        self.projected.bind_to_storage_buffer(2)
        for base in range(0, self.n, self.chunk):
            count = min(self.chunk, self.n - base)
            self.params.bind_to_storage_buffer(0, offset=base * 64, size=count * 64)
            if self.k:
                stride = self.k * 12
                self.sh.bind_to_storage_buffer(1, offset=base * stride, size=count * stride)
            else:
                self.sh.bind_to_storage_buffer(1)
            p["u_base"].value = base
            p["u_count"].value = count
            p.run(group_x=(count + _WORKGROUP - 1) // _WORKGROUP)

    def render(self, camera, target: FloatTarget, *, order: np.ndarray | None = None,
               background=(0.0, 0.0, 0.0), sh_degree: int | None = None,
               scale_modifier: float = 1.0) -> None:
        """Draw the cloud from ``camera`` into ``target`` (cleared to ``background``).

        ``order``: [M] uint32 back-to-front splat indices (default: :func:`depth_order` for
        this camera, computed now).  An order sorted for another camera still draws every
        splat -- just possibly in a stale order, which the app replaces as soon as its sorter
        catches up.
        """
        if (camera.width, camera.height) != target.size:
            raise GszError(f"camera is {camera.width}x{camera.height} but the target is "
                           f"{target.width}x{target.height}")
        if order is None:
            order = depth_order(self.cloud.positions, camera)
        order = np.ascontiguousarray(order, np.uint32)
        if len(order) > self.n:
            raise GszError("render order is longer than the scene")
        ctx = self.ctx
        t0 = time.perf_counter()
        self.preprocess(camera, sh_degree=sh_degree, scale_modifier=scale_modifier)
        t1 = time.perf_counter()
        target.fbo.use()
        ctx.viewport = (0, 0, target.width, target.height)
        bg = [float(v) for v in background]
        ctx.clear(bg[0], bg[1], bg[2], 0.0)
        if len(order):
            self.order_buf.write(order.tobytes())
            self.order_buf.bind_to_storage_buffer(3, size=len(order) * 4)
            self.projected.bind_to_storage_buffer(2)
            mgl = self._moderngl
            ctx.disable(mgl.DEPTH_TEST | mgl.CULL_FACE)
            ctx.enable(mgl.BLEND)
            ctx.blend_func = mgl.ONE, mgl.ONE_MINUS_SRC_ALPHA
            ctx.blend_equation = mgl.FUNC_ADD
            self.prog["u_size"].value = (float(target.width), float(target.height))
            self.vao.render(mode=mgl.TRIANGLE_STRIP, vertices=4, instances=len(order))
            ctx.disable(mgl.BLEND)
        t2 = time.perf_counter()
        self.last_times = {"preprocess_s": t1 - t0, "draw_s": t2 - t1}


def render_image(cloud: GaussianCloud, camera, *, ctx=None, background=(0.0, 0.0, 0.0),
                 sh_degree: int | None = None, scale_modifier: float = 1.0) -> np.ndarray:
    """[H, W, 3] float32 linear RGB (background composited, not clamped): one GL frame of
    ``cloud`` from ``camera`` -- the GL counterpart of ``gsz.evaluation.render.render(...).image``.
    Creates a headless EGL context when ``ctx`` is None."""
    own = ctx is None
    ctx = ctx or create_headless_context()
    try:
        r = SplatRenderer(ctx, cloud)
        target = FloatTarget(ctx, camera.width, camera.height)
        r.render(camera, target, background=background, sh_degree=sh_degree,
                 scale_modifier=scale_modifier)
        img = target.read()[..., :3]
        ctx.finish()
        target.release()
        r.release()
        return np.ascontiguousarray(img)
    finally:
        if own:
            ctx.release()
