"""The harness's third stage: the figures of ``results.json`` from the blocks' sums.

The figures per case and row (:mod:`.finalise`, with paired differences :mod:`.paired` and
training seeds :mod:`.seeds`; a kind's own figures come from the metrics it declares,
:mod:`pmsr_nn.methods.kind_metrics`), the typed reading of a ``results.json`` (:mod:`.typed`,
:mod:`.result_rows`) and two results side by side (:mod:`.compare`). Imports the scenario and run stages only.
"""
