"""Stage package for cache-key tests: ingest as declared before ``ingest.sample_bits``
existed, with the cheap fake downstream stages of ``arroyo_ingest_stages``."""
