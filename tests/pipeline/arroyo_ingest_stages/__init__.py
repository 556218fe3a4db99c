"""Stage package for bad-input tests: the real ingest, cheap fake downstream stages."""
