"""The ``evaluate`` and ``export`` commands: a trained run's policy loaded (``policy``), evaluated, exported."""
