"""The harness's second stage: a prepared scenario run in blocks of Monte Carlo runs.

Drawing each block's truth and products and calling every method on them (:mod:`.blocks`),
scoring the estimates into per-block sums (:mod:`.scoring`), the sums of a run or shard and which
blocks a shard runs (:mod:`.block_sums`), banks of one-block shards (:mod:`.block_bank`) and the
one runner (:mod:`.runner`). Imports the scenario stage only.
"""
