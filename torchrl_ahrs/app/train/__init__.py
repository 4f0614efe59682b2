"""The ``train`` and ``sweep`` commands: building a run, the iteration, checkpoints, start-up checks, the
periodic video, and reading what a run wrote (``runs``, also read by ``report`` and ``generate_aux``)."""
