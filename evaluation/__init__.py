"""gsz.evaluation: seeing a scene through cameras -- :mod:`~gsz.evaluation.cameras`, the CPU
reference renderer :mod:`~gsz.evaluation.render`, PSNR/SSIM :mod:`~gsz.evaluation.metrics` and
:mod:`~gsz.evaluation.evaluate` (gsz-eval's scoring).  Not codec: none of it reads or writes a
.gsz; the encoder's search and the viewer both judge renders with it (it imports only gsz.decoder).

The ``gsz-eval`` command line stays in :mod:`gsz.encoder.eval_cli`: its ``--rd`` runs the size
search, and this package must not import the encoder, which imports it.
"""
