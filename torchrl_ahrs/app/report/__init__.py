"""The ``report`` command: tables, figures and ``report.md`` of one or more sweeps."""
