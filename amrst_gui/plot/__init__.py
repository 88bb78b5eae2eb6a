"""The Plot window: a forest plot's scans run through ``amrst.plot``, and its review.

``window`` is the window: it runs the plot, shows it and saves the technician's
review. Its parts: ``scans`` the scans listed for the next run, ``area`` the plot
radius and centre, ``links`` the links and what the next run does with them,
``tree_list`` the trees listed, ``tables`` what fills the links and trees tables,
``tree`` the selected tree's panel (drawn by ``tree_slice`` and ``tree_side``),
``stem_map`` the plot from above, ``menus`` the menus, ``typed`` coordinates as
typed; ``jobs`` is what the window runs in the engine process and reads back (no Qt).
"""
