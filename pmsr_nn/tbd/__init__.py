"""Track-before-detect on range-Doppler maps (the Remote Sensing 2020 seed, ``001``).

* :mod:`.maps`: the GNSS multistatic geometry, the map grid, the target response and the maps;
* :mod:`.likelihood`: the Rician likelihood ratio of a state on a sub-area of cells, the
  maximum-likelihood amplitude behind the online SNR estimate;
* :mod:`.multibernoulli`: the SMC multi-Bernoulli filter (PMB, ICMB, modified ICMB);
* :mod:`.detect`: detect-then-track on the same maps, for comparison;
* :mod:`.scene`: what forms a case's maps (a scenario's ``rd_maps`` section: satellites seen by one
  receiver, or the recipe's transmitter-receiver pairs), a stand-alone scene of satellites and one
  target for the tests, and the ``rd_maps`` product;
* :mod:`.run`: one filter on one block of maps (what :mod:`pmsr_nn.methods.tbd` calls).
"""
