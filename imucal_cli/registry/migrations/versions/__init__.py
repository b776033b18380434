"""The registry's schema revisions, oldest first (``0001_initial``, ``0002_acceptance``,
``0003_imus``)."""
