"""The report stage: markdown, plots and comparison rendered from results documents."""
