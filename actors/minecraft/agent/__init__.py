"""actors/minecraft/agent."""
