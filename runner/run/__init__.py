"""The run stage: processes, the native core, kernel read-back, and the pure evaluation of what ran."""
