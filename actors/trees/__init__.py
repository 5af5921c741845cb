"""Hard-coded policies written as py_trees behaviour trees (the Pendulum swing-up of sec. IV-B)."""
