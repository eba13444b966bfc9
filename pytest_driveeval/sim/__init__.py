"""Simulators: drive agents through scenes, step by step.

What every simulator shares: the kinematic state of a batch of agents
(:mod:`.state`, ``AgentState``) and the models that step it from an action
(:mod:`.dynamics`: the requested pose taken as is, a unicycle with limits, a
kinematic bicycle).  Each simulator lives in its own subpackage;
:mod:`.logreplay` drives the ego through logged scenes while the other agents
replay the log.

Importing this package is light (numpy only); the simulators import torch.
"""
