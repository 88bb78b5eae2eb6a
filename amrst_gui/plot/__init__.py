"""The Plot window: a forest plot's scans run through ``amrst.plot``, and its review.

``window`` is the window; ``jobs`` what it runs in the engine process and reads back
(no Qt); ``tables`` the links and trees tables; ``tree`` the selected tree's panel,
drawn by ``tree_slice`` and ``tree_side``; ``stem_map`` the plot from above.
"""
