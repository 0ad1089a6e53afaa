"""Track-before-detect on range-Doppler maps (the Remote Sensing 2020 seed, ``001``).

* :mod:`.maps`: the GNSS multistatic geometry, the map grid, the target response and the maps;
* :mod:`.likelihood`: the Rician likelihood ratio of a state on a sub-area of cells, the
  maximum-likelihood amplitude behind the online SNR estimate;
* :mod:`.multibernoulli`: the SMC multi-Bernoulli filter (PMB, ICMB, modified ICMB);
* :mod:`.detect`: detect-then-track on the same maps, for comparison;
* :mod:`.scene`: a study's scene (satellites, target, frames) and the ``rd_maps`` product.
"""
