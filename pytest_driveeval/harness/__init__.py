"""The pytest side: scenario collection, the fixtures, the options, per-item failures and
status lines, the results a session writes and its run folders.  ``plugin.py`` (the
``pytest11`` entry point) holds the hooks that call these modules."""
