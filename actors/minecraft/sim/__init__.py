"""actors/minecraft/sim."""
