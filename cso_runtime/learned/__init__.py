"""The learned CSO policy (section 3.4): graph state, GNN actor-critic, Gymnasium env and PPO.

Importing this package needs torch; ``cso_runtime.policies`` only imports it when a learned method
is asked for.
"""
