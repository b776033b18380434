"""The device's sample clock against the host's arrival times."""
