"""Persistence and reporting: typed records, the SQLite store, the HTML report and recorded logs (SPEC C10)."""
