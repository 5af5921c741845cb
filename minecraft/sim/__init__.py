"""The simulated Minecraft world server: world, terrain, physics, player, inventory, crafting,
entities, rendering and observations, served over MalmoEnv's protocol by a process pool."""
