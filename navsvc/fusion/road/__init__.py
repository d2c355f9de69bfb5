"""The road-vehicle filter of Mayhew 1999: :mod:`.motion` (the 8-state layout and process
model), :mod:`.measurements` (one model per sensor reading, and the road constraint),
:mod:`.filter` (``RoadFilter``: the EKF policy, stationary detection), :mod:`.rules` and
:mod:`.fuzzy` (the thesis's GPS modes). Sessions reach it through
:class:`navsvc.fusion.FusionEngine`.
"""
