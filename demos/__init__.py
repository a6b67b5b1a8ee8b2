"""``secuav-demo``: the closed-loop demos (simulator, proxy, broker and a MAVSDK controller, together).

A demo is an orchestrator: it starts the parts as separate processes exactly as
a user would (so the services never import each other), flies, tears
everything down, and scores the flight from the simulator's ground truth.
"""
