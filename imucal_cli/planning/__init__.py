"""Planning a capture from the models' Fisher information: what a design of poses and turns
determines at a fit (``information``: each target term's std; ``determined``: the null space,
which parameters or combinations it leaves free) and what to capture next (``next_pose``: the
pose or turn that helps most, how long to hold). Pure: arrays in, dataclasses out."""
