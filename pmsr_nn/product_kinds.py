"""Every kind of sensor product a tracker can read, by name (:data:`PRODUCTS`).

A product is what one kind of tracker reads of a case's truth (:mod:`pmsr_nn.simulation.products`
describes them). Each kind's maker lives with what it simulates: the measurement streams and the
simulated detections in :mod:`pmsr_nn.simulation.products`, detections from simulated signals in
:mod:`pmsr_nn.frontend.chain`, range-Doppler maps in :mod:`pmsr_nn.tbd.scene`. This module sits
above all three and lists every kind here, so the lower modules never write into a registry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from .frontend.chain import front_end_scans
from .simulation.products import (Detections, SensorSetup, Truth, initiation_prior, make_simulated_detections,
                                  make_streams)
from .tbd.scene import make_rd_maps


@dataclass(frozen=True)
class ProductKind:
    """A product: ``make(sensing, truth, g, g_prior)``; ``stream`` numbers its own generator."""

    name: str
    stream: int
    make: Callable
    description: str


def make_detections(sensing: SensorSetup, truth: Truth, g: torch.Generator, g_prior: torch.Generator) -> Detections:
    """Detections from the signal chain (:func:`~pmsr_nn.frontend.chain.front_end_scans`, from
    ``g``, then the prior from ``g_prior``) when the sensing has a front end, else drawn from the
    detection model (:func:`~pmsr_nn.simulation.products.make_simulated_detections`)."""
    if sensing.front_end is None:
        return make_simulated_detections(sensing, truth, g, g_prior)
    scans, record = front_end_scans(truth.x, truth.alive, sensing.detection_model, sensing.front_end, g)
    return Detections(scans, initiation_prior(truth, sensing.prior_sd, g_prior), None, record)


def _by_name(*kinds: ProductKind) -> dict[str, ProductKind]:
    names, streams = [k.name for k in kinds], [k.stream for k in kinds]
    if len(set(names)) < len(names) or len(set(streams)) < len(streams):
        raise ValueError(f"product kinds need distinct names and streams: {list(zip(names, streams))}")
    return {k.name: k for k in kinds}


PRODUCTS: dict[str, ProductKind] = _by_name(
    ProductKind("measurements", 1, make_streams,
                "each target's own measurement stream, association known"),
    ProductKind("detections", 2, make_detections,
                "per sensor and scan: detections with missed targets and clutter"),
    ProductKind("rd_maps", 3, make_rd_maps,
                "per transmitter-receiver pair and frame: a range-Doppler map after coherent integration "
                "(track-before-detect)"),
)
"""Product kinds by name, in the order the runner draws them."""

