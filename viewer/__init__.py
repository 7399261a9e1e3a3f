"""gsz.viewer: ``gsz-view``, the interactive viewer that compares decoded splats with the original.

Modules (importing this package imports none of them, so it costs nothing):

* :mod:`~gsz.viewer.gl_renderer` -- moderngl splat renderer with the CPU reference renderer's
  semantics (compute-shader EWA projection + SH, instanced quads, premultiplied blending)
* :mod:`~gsz.viewer.sorter` -- back-to-front depth sort on a worker thread
* :mod:`~gsz.viewer.camera_control` -- orbit / pan / zoom / fly camera state (numpy)
* :mod:`~gsz.viewer.state` -- settings, scenes and :class:`ViewState` (the GL-free view state)
* :mod:`~gsz.viewer.app` -- :class:`ViewerApp` (a ViewState): input events, GL frames
* :mod:`~gsz.viewer.ui` -- the imgui-bundle panel; :mod:`~gsz.viewer.window` -- glfw window
* :mod:`~gsz.viewer.budgets` -- background encodes at ``--budgets``
* :mod:`~gsz.viewer.cli` -- the ``gsz-view`` command (``main``)
"""
