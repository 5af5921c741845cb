"""actors/minecraft/malmo."""
