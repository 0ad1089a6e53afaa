"""Track management as method options: what every kind that starts its own tracks shares (not a
method kind itself).

A kind that offers ``initiation: oracle | detections`` (S-/P-MSJPDA, PMHT) adds
:data:`MANAGEMENT_OPTIONS` to its options; a kind that always starts its own tracks adds
:data:`OWN_TRACK_OPTIONS` (the same without ``initiation``). Both read their components with
:func:`management` and refuse what could never confirm a track with :func:`check_initiation`
(give it as the kind's ``check_sensing``). The components are :mod:`pmsr_nn.trackers.management`'s.

Options:

* ``initiation``: ``oracle`` (handed each target's birth: a reference row) or ``detections``;
* the initiator: ``init_pairs``, ``init_gate_probability``, ``birth_velocity_sd_mps``. It follows
  what the detections measure: with azimuth, the fix initiator (each pair's (range, azimuth)
  fixes a position; fixes of ``init_pairs`` pairs that agree start a track); without, the
  spherical initiator (every combination of one detection per pair whose joint fit of ranges and
  rates passes the gate). ``fix_covariance`` (the fix initiator's): ``linearised`` (default,
  ``H^-1 R H^-T``) or ``unscented`` (the spread of the fixes of sigma points, BP's seed
  covariance: consistent where the linearised one is overconfident across the range,
  evaluate/fix_consistency.py);
* ``init_scans``: 1 (default) a tentative track starts from one scan's candidate; 2 or 3 only
  from candidates consistent over that many consecutive scans (the multi-scan initiator,
  :mod:`pmsr_nn.trackers.multi_scan_initiator`, around the single-scan one), scan to scan within
  ``init_scan_gate_probability`` of the chi-square of position and velocity; without azimuth the
  spherical initiator then hands on every consistent combination of a scan
  (``init_scan_candidates: all``, default) or its greedy exclusive selection (``greedy``);
* M-of-N confirmation ``confirm_m`` / ``confirm_n``, a hit at ``hit_pairs`` pairs, deletion after
  ``delete_misses`` misses, and by existence below ``delete_existence`` (default null: none;
  below ``report_existence``, else refused);
* existence: ``survival``, ``initial_existence``, ``report_existence``; its update ``existence``:
  ``ipda`` (default: each pair's gated likelihood sum) or ``jipda`` (the association
  probabilities, so a track that only shares another track's detections fades);
* which detections start no track, ``explained_by``: ``gate`` (default: those a track gates) or
  ``association`` (those more probably some track's than clutter, by the association
  probabilities); PMHT has no gate and reads its association weights either way;
* the coalescence test (:mod:`pmsr_nn.trackers.coalescence`): ``merge_scans`` (default null: no
  merging), two confirmed tracks whose positions and velocities agree within
  ``merge_probability`` of their joint covariance at that many consecutive scans are merged,
  the older id survives.

  :data:`DUPLICATE_FREE` (``existence: jipda, explained_by: association, merge_scans: 3,
  delete_existence: 0.01``, chosen on one_sky draws no recorded study uses, seed 1000) is the
  duplicate-free management of issue 55: without the existence deletion, two tracks on one drone
  whose JIPDA existences both fade stay unreported and take its detections, so no new track
  starts (a drone of one_sky's formation went 58 scans without a track that way). It is not the
  default yet: the recorded studies' rows that start their own tracks were made with the
  defaults above and reproduce from them; it becomes the default when they are re-recorded
  (evaluate/RESULTS.md, "Belief propagation", what is left);
* the innovation bias test (:data:`BIAS_OPTIONS`: ``bias_window`` null for none).
"""

from __future__ import annotations

from dataclasses import replace

from ..errors import ConfigError
from ..trackers.fix_initiator import FIX_COVARIANCES, FixInitiator
from ..trackers.jpda import floored_clutter_density
from ..trackers.coalescence import Coalescence
from ..trackers.management import DELETE_EXISTENCE, EXPLAINED_BY, MERGE_SCANS, BiasTest, Confirmer, Deleter, Management
from ..trackers.multi_scan_initiator import MultiScanInitiator
from ..trackers.roles import Initiator
from ..trackers.spherical_initiator import SphericalInitiator
from . import Option, ReadWhen, method_kind

INITIATIONS = ("oracle", "detections")

EXISTENCE_UPDATES = ("ipda", "jipda")
"""The existence update: ``ipda`` each pair's gated likelihood sum; ``jipda`` the association
probabilities (:attr:`pmsr_nn.trackers.management.Management.shared_existence`)."""

MAX_INIT_SCANS = 3
"""Most consecutive scans ``init_scans`` chains candidates over."""

INIT_SCAN_CANDIDATES = ("all", "greedy")
"""Which of a scan's consistent combinations the spherical initiator hands the multi-scan one:
``all`` (the best :data:`~pmsr_nn.trackers.spherical_initiator.MAX_CANDIDATES` per run; the
scan-to-scan gate prunes them) or ``greedy`` (the exclusive selection of single-scan initiation)."""

INIT_SCAN_OPTIONS = {"init_scans": Option(1, int, 1, MAX_INIT_SCANS),
                     "init_scan_gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12,
                                                          read_when=ReadWhen("init_scans", (2, 3))),
                     "init_scan_candidates": Option("all", str, choices=INIT_SCAN_CANDIDATES,
                                                    read_when=ReadWhen("init_scans", (2, 3)))}
"""Multi-scan initiation (module docstring): shared with the kinds whose initiator is the
spherical or fix one (``bp`` without azimuth)."""

COALESCENCE_OPTIONS = {"merge_scans": Option(None, int, 0, 10_000, nullable=True, null="no merging"),
                       "merge_probability": Option(0.99, float, 1e-6, 1.0 - 1e-12, read_when=ReadWhen("merge_scans"))}
"""The coalescence test's options (:func:`coalescence`): the trackers' and the PHD labelling's."""


def coalescence(option) -> Coalescence | None:
    """The coalescence rule of a row's options (``option``: :meth:`MethodSpec.option`); None without ``merge_scans``."""
    merge = option("merge_scans")
    return None if merge is None else Coalescence(int(merge), float(option("merge_probability")))


OWN_TRACK_OPTIONS = {"init_pairs": Option(None, int, 1, 64, nullable=True,
                                          null="2 with azimuth (fix initiator; 3 from lists pooled per receiver), else "
                                               "every pair (spherical initiator)"),
                     "init_gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
                     "fix_covariance": Option("linearised", str, choices=FIX_COVARIANCES),
                     **INIT_SCAN_OPTIONS,
                     "birth_velocity_sd_mps": Option(20.0, float, 1e-3, 1e5),
                     "confirm_m": Option(2, int, 1, 62), "confirm_n": Option(3, int, 1, 62),
                     "hit_pairs": Option(2, int, 1, 64), "delete_misses": Option(2, int, 0, 10_000),
                     "delete_existence": Option(None, float, 1e-12, 1.0 - 1e-12, nullable=True,
                                                null="no deletion by existence"),
                     "survival": Option(0.99, float, 1e-6, 1.0), "initial_existence": Option(0.5, float, 1e-6, 1.0),
                     "report_existence": Option(0.5, float, 0.0, 1.0),
                     "existence": Option("ipda", str, choices=EXISTENCE_UPDATES),
                     "explained_by": Option("gate", str, choices=EXPLAINED_BY),
                     **COALESCENCE_OPTIONS}
"""The management options of a kind that always starts its own tracks."""

DUPLICATE_FREE = {"existence": "jipda", "explained_by": "association", "merge_scans": MERGE_SCANS,
                  "delete_existence": DELETE_EXISTENCE}
"""The duplicate-free management's options (module docstring): a row's ``options`` with these."""

MANAGEMENT_OPTIONS = {"initiation": Option("oracle", str, choices=INITIATIONS),
                      **{k: replace(o, read_when=o.read_when or ReadWhen("initiation", ("detections",)))
                         for k, o in OWN_TRACK_OPTIONS.items()}}
"""How tracks start and, with ``initiation: detections`` (read only then), the track management."""

BIAS_OPTIONS = {"bias_window": Option(None, float, 1.0, 1e4, nullable=True, null="no innovation bias test"),
                "bias_probability": Option(0.999, float, 0.5, 1.0 - 1e-12, read_when=ReadWhen("bias_window")),
                "bias_burn_in": Option(10, int, 0, 10_000, read_when=ReadWhen("bias_window"))}
"""The innovation bias test (:mod:`pmsr_nn.trackers.innovation_bias`), for sequential trackers."""


def clutter_density(sensing) -> float:
    """Expected clutter per unit of one pair's measurement space (a ``SensorSetup``), floored:
    a tracker needs a positive clutter density even where none was simulated."""
    return floored_clutter_density(sensing.pair_clutter(), sensing.detection_model.components)


def starts_own_tracks(spec) -> bool:
    """Whether the row starts its own tracks: ``initiation: detections``, or a kind without an
    ``initiation`` option."""
    return "initiation" not in method_kind(spec.kind).options or spec.option("initiation") == "detections"


def bias_test(spec) -> BiasTest | None:
    """The innovation bias test a row's options ask for (``bias_window`` null or absent: none)."""
    options = method_kind(spec.kind).options
    if "bias_window" not in options or spec.option("bias_window") is None:
        return None
    action = spec.option("bias_action") if "bias_action" in options else "delete"
    return BiasTest(float(spec.option("bias_window")), float(spec.option("bias_probability")), action,
                    int(spec.option("bias_burn_in")))


def initiator(single: Initiator, spec) -> Initiator:
    """The initiator a row's ``init_scans`` asks for: ``single`` (1), or the multi-scan initiator
    around it (2 or 3; :class:`MultiScanInitiator`, its gate ``init_scan_gate_probability``), a
    spherical one then giving every consistent combination (``init_scan_candidates: all``) or its
    greedy exclusive selection (``greedy``)."""
    scans = int(spec.option("init_scans"))
    if scans == 1:
        return single
    if isinstance(single, SphericalInitiator) and spec.option("init_scan_candidates") == "all":
        single = replace(single, exclusive=False)
    return MultiScanInitiator(single, scans, float(spec.option("init_scan_gate_probability")))


def management(spec, sensing, pooled: bool = False) -> Management:
    """The track-management components a row's options describe (module docstring).

    ``init_pairs`` null: 2 pairs for the :class:`FixInitiator`, 3 for a row that reads lists
    pooled per receiver (``pooled``: every detection there is fixed under each transmitter, so
    two pairs agree by chance far more often, and a track started between two drones in
    formation lives on beside theirs); every pair for the :class:`SphericalInitiator`, whose
    :meth:`~SphericalInitiator.check` refuses what neither can start tracks from."""
    o = spec.option
    pairs = o("init_pairs")
    velocity_sd, gate = float(o("birth_velocity_sd_mps")), float(o("init_gate_probability"))
    if "azimuth" in sensing.detection_model.components:
        single = FixInitiator(velocity_sd, (3 if pooled else 2) if pairs is None else int(pairs), gate,
                              o("fix_covariance"))
    else:
        single = SphericalInitiator(velocity_sd, None if pairs is None else int(pairs), gate)
    deleter = Deleter(int(o("delete_misses")), min_existence=float(o("delete_existence") or 0.0))
    return Management(initiator(single, spec), Confirmer(int(o("confirm_m")), int(o("confirm_n"))), deleter,
                      sensing.prior_sd, int(o("hit_pairs")), float(o("survival")), float(o("initial_existence")),
                      float(o("report_existence")), bias_test(spec),
                      coalescence(o),
                      o("existence") == "jipda", o("explained_by"))


def check_initiation(spec, sensing, pooled: bool = False) -> None:
    """Refuses, in one line naming the row, track management that could never confirm a track,
    detections no initiator can start tracks from, and an innovation bias test on a row that
    does not start its own tracks or on P-MSJPDA (``pooled``: the row reads lists pooled per
    receiver). A kind's ``check_sensing``."""
    if bias_test(spec) is not None and (not starts_own_tracks(spec) or spec.kind == "p_msjpda"):
        raise ConfigError(f"method {spec.name!r}: the innovation bias test (bias_window) acts on the tracks a sequential "
                          f"tracker starts itself: set initiation: detections on s_msjpda, or "
                          f"bias_window: null")
    if not starts_own_tracks(spec):
        return
    delete, report = spec.option("delete_existence"), float(spec.option("report_existence"))
    if delete is not None and float(delete) >= report:
        raise ConfigError(f"method {spec.name!r}: delete_existence ({delete}) must be below report_existence ({report}): "
                          f"a confirmed track would be deleted before it could be reported")
    if "init_scan_candidates" in spec.options and "azimuth" in sensing.detection_model.components:
        raise ConfigError(f"method {spec.name!r}: option init_scan_candidates is read only without azimuth (the "
                          f"spherical initiator's combinations); the detections measure "
                          f"{list(sensing.detection_model.components)}")
    try:
        management(spec, sensing, pooled).check(sensing.detection_model, "initiation from detections", pooled=pooled)
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r}: {exc}") from None
