"""What the ingest stage (:mod:`toolkit.stages.ingest`) does with a log's messages, below the
stage: topic plans (:mod:`.plans`), the roles and their converters (:mod:`.roles`,
:mod:`.converters`, :mod:`.rows`, :mod:`.attitude`), a batch's screening (:mod:`.screen`), exact
duplicates (:mod:`.dedup`), the per-table reorder buffers (:mod:`.reorder`), stray stamps
(:mod:`.timecheck`), the per-topic accounting (:mod:`.accounts`) and one pass's tables
(:mod:`.run`). The stage module keeps the workspace side: the log's identity, its record and
the order of the steps.
"""
