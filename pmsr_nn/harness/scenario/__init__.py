"""The harness's first stage: a scenario file's study, checked and prepared.

The YAML schema (:mod:`.schema` with :mod:`.case_spec`, :mod:`.method_spec`, :mod:`.world`), the
designed flights (:mod:`.trajectories`), the tuned options (:mod:`.tuning`), the paper's reference
numbers (:mod:`.references`), and the preparation (:mod:`.prepare_designed`) into what the later
stages read (:mod:`.prepared`): the cases, their bounds (:mod:`.case_bounds`), the settings and the
definitions of the figures (:mod:`.definitions`). Imports no later stage.
"""
