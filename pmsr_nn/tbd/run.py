"""One filter on one block of maps: what the method kinds (:mod:`pmsr_nn.methods.tbd`), the
benchmark and the tests call.

:func:`run_filter` runs a filter (the seed's map likelihood, or detect-then-track when given a
:class:`~.detect.DetectSpec`) on a block's ``rd_maps`` product: the kinds' body, the one path
that runs a filter. :func:`simulate_and_run` draws the block of a stand-alone
:class:`~.scene.TBDScene` with the same pieces the harness's runner uses (the truth's ``draw``,
the ``rd_maps`` product's maker :func:`~.scene.make_rd_maps`) and runs :func:`run_filter` on it,
but from its own streams: truth ``(seed, 0)``, maps ``(seed, 1)``, filter ``(seed, 2)``. The
statistical checks of ``tests/test_tbd.py`` and ``tests/test_tbd_snr.py`` and the figures
``evaluate/tbd_checks.py`` recorded in ``evaluate/RESULTS.md`` (issue 37's table) were measured on
those draws; the runner's streams (``(seed, case, block[, stream])``, the filter's
``(seed, case, block, crc32(name))``) can not give them, so running these through the runner
would change recorded figures.
"""

from __future__ import annotations

import torch

from ..motion import motion_model
from ..rng import seeded_generator
from ..simulation.products import SensorSetup, Truth
from .detect import DetectionLikelihood, DetectSpec
from .multibernoulli import MapLikelihood, MBOutput, MBSpec, MultiBernoulliTBD
from .scene import MapScene, RangeDopplerMaps, TBDScene, make_rd_maps


def run_filter(scene: MapScene, spec: MBSpec, product: RangeDopplerMaps, g: torch.Generator,
               detect: DetectSpec | None = None) -> MBOutput:
    """The CV multi-Bernoulli filter of ``spec`` over every frame of ``product`` (its runs batched),
    on the device of the product's maps (``g`` a generator of that device)."""
    cv = motion_model("cv", 2)
    dt = scene.frame_s
    dev = product.device
    mb = MultiBernoulliTBD(spec, scene.birth_box, scene.maps.lobe_cells, cv.F(dt, device=dev),
                           cv.noise_factor(dt, 1.0, device=dev))
    snr = torch.tensor(scene.snr_db, dtype=torch.float64, device=dev)
    if detect is not None:
        measure = DetectionLikelihood(detect, product.frame, scene.cells, scene.maps.lobe_cells, scene.maps.noise_power,
                                      snr)
    else:
        measure = MapLikelihood(spec, product.frame, scene.cells, scene.maps.lobe_cells, scene.maps.noise_power, snr, g)
    return mb.run(scene.frames, measure, scene.cells, product.B, g)


def draw_maps(scene: TBDScene, runs: int, seed: int) -> tuple[Truth, RangeDopplerMaps]:
    """The truth of ``runs`` runs and their maps product (generators ``(seed, 0)`` and ``(seed, 1)``)."""
    truth = scene.truth().draw(runs, seeded_generator(seed, 0))
    return truth, make_rd_maps(SensorSetup(model=None, prior_sd=None, rd_maps=scene.scene), truth,
                               seeded_generator(seed, 1), None)


def simulate_and_run(scene: TBDScene, spec: MBSpec, runs: int, seed: int,
                     detect: DetectSpec | None = None) -> tuple[MBOutput, Truth]:
    """Draw ``runs`` runs of the scene and run the filter on them (its generator ``(seed, 2)``)."""
    truth, product = draw_maps(scene, runs, seed)
    return run_filter(scene.scene, spec, product, seeded_generator(seed, 2), detect), truth
