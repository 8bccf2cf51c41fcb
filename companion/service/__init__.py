"""``companion run`` as a service on the vehicle's companion computer: its configuration file
(``config``), its logs for journald (``logs``), the live status page (``status`` the state,
``feed`` what fills it from the resident loop, ``http`` the server and ``static/`` the page) and
the worst case of a stop (``stop_budget``, what the systemd unit's TimeoutStopSec must exceed).

A floor of its own: above the procedures (it runs the resident loop) and the rehearsal, below the
command line (which reads the flags and hands them over).
"""
