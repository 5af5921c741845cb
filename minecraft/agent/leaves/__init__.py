"""Leaves of the obtain-diamond behaviour tree (``minecraft.agent.diamond_tree``): what
the agent perceives (``percept``), the per-tick command sheet and the blackboard context
(``context``), steering and aiming (``control``), conditions, crafting and equipping,
the A* travel sub-tree, goals (what to mine, exploring, descending, drops) and survival."""
