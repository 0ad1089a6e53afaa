"""Passive radar front end: from complex baseband samples to the detections product.

One concept per module: :mod:`.fm_signals` simulates an FM transmitter's reference and
surveillance channels for one coherent processing interval (CPI), :mod:`.cancellation` removes
the direct path and static clutter (ECA, NLMS), :mod:`.ccf` forms the range-Doppler map (2D-CCF,
Eq. 1 of the Daniyan et al. seed), :mod:`.cfar` thresholds it (2-D OS-CFAR), :mod:`.centroid`
turns connected detections into (bistatic range, Doppler, SNR) measurements and :mod:`.chain`
runs the whole chain scan by scan into :class:`~pmsr_nn.simulation.detections.Scans`.
"""
