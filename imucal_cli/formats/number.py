"""The text of one decimal number, as imucal reads it everywhere (no NumPy: the CLI's argument
coercion imports it at start-up)."""

import re

#: A plain ASCII decimal number, optionally signed, with an optional exponent; no backtracking
#: on long digit runs (the older ``[0-9]+\.?[0-9]*`` took seconds on 20,000 digits).
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
