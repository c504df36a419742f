"""How far the simulator can be trusted: scenes with known answers, the
explicit-mesh reference, and the error budget.

- :mod:`clsim.validation.testscenes`: built-in scenes with closed-form answers;
- :mod:`clsim.validation.meshref`: the pulse traced against the tree's mesh;
- :mod:`clsim.validation.budget`: simulated waveforms against that reference.
"""
