"""The results stage: the typed, versioned results document, its files, shards merged."""
