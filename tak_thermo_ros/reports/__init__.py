"""HTML reports (matplotlib): ``diagnose --report`` (:mod:`.diagnose`) and ``fit-fleet``'s batch (:mod:`.fleet`).

Nothing is imported here.
"""
