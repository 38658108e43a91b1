"""The scenario stage: YAML text to typed, validated, expanded cells and their planned threads."""
