"""Multi-target trackers and the parts they share.

* :mod:`.assignment_2d`: ranked 2-D assignment (Murty);
* :mod:`.assignment`: (S+1)-D assignment by Lagrangian relaxation, and its ranked events;
* :mod:`.gating`: chi-square gates and Gaussian association likelihoods;
* :mod:`.clustering`: tracks that compete for detections;
* :mod:`.jpda`: association probabilities from ranked events;
* :mod:`.bp_association`: one pair's association, existence and new-target beliefs by loopy
  belief propagation (Williams & Lau; Meyer et al. 2018); :mod:`.bp_associator`: the associator
  that updates tracks with them pair by pair (no method kind yet);
* :mod:`.roles`: the roles a tracker is assembled from (associator, track management) and
  what they hand each other; :mod:`.loop`: the one tracker loop that runs an assembly;
* :mod:`.jpda_associators`: the S-MSJPDA and P-MSJPDA associators;
* :mod:`.handed_births`: the management of a tracker handed its targets' births;
  :mod:`.own_tracks`: of one that starts, confirms and deletes its own (:mod:`.management`);
* :mod:`.msjpda`: S-MSJPDA, P-MSJPDA handed the births, and the true-assignment reference tracker;
* :mod:`.msjpda_managed`: S-/P-MSJPDA starting, confirming and deleting their own tracks,
  with the innovation bias test of :mod:`.innovation_bias`.
"""

from .assignment import SDSolution, m_best_sd, sd_assign
from .assignment_2d import murty
from .msjpda import JPDASettings, MultiTargetResult, msjpda, true_assignment_ukf

__all__ = ["SDSolution", "m_best_sd", "murty", "sd_assign", "JPDASettings", "MultiTargetResult", "msjpda",
           "true_assignment_ukf"]
