"""Procedures over the vehicle link: the runner, restore points and every procedure the companion runs (SPEC §5, layer 4)."""
