"""The self-contained rehearsal: the simulator as a child process, the companion over MAVLink, a
report (the README's first command). A library below both the command line (``companion.cli``) and
the sweeps (``companion.sweep``), which run many rehearsals: ``rehearsal`` runs one, ``launcher``
starts the simulator process, ``reproducibility`` says whether a run was a function of its seed."""
