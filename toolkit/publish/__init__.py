"""Commands over a finished workspace that publish its results to people and other tools:
``terrain export`` (a labelled dataset, :mod:`toolkit.publish.export`) and ``terrain viz``
(a Foxglove view of one log, :mod:`toolkit.publish.viz`). Not pipeline stages: they read
what the stages wrote and change nothing of the workspace."""
