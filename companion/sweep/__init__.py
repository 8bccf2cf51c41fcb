"""Parameter sweeps: many independent rehearsals on a Dask cluster (``companion sweep``).

* :mod:`companion.sweep.spec` — what varies (presets, seeds, currents, noise, vehicle perturbations,
  thrust lists, procedure options), read from a JSON/YAML file or flags, expanded into cases, each
  keyed by the hash of its inputs;
* :mod:`companion.sweep.case` — one case: ``companion rehearse --json`` in a child process with its
  own temporary directory, ports (bound to 0) and logs, reduced to one summary row;
* :mod:`companion.sweep.engine` — runs the cases on a ``dask.distributed`` cluster (a local one by
  default, or an existing scheduler) or a plain loop, records every finished row, resumes, shows
  progress and stops cleanly;
* :mod:`companion.sweep.report` — the HTML sweep report.
"""
