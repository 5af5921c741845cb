"""The rest of Minecraft 1.11's blocks: every block type a Malmo mission may name that
``blocks.py`` does not model in full.

Each is drawn, observed (grids, ray) and touched under its own name, with Minecraft's
hardness, tool and drop, but behaves as the simplest block of its kind: stairs, slabs,
fences, walls, doors and panes are full solid cubes (an agent can jump onto a fence);
flowers, crops, rails, torches, signs, carpets, ladders and vines are passable and do not
collide (ladders and vines cannot be climbed); machines (pistons, redstone, command
blocks, hoppers, spawners) do nothing; containers hold nothing; cactus and magma do not
hurt, ice is not slippery, soul sand and cobwebs do not slow, slime does not bounce.
``NOTES`` names the category of each approximation for the mission-load warning. Fire,
portals and end gateways are not in the table: the simulator refuses missions that
place them.

Table columns: name, hardness (``inf``: unbreakable), tool (``-``: none), harvest level
(hand/wood/stone/iron), drop (``=``: itself, ``-``: nothing, ``item*n``), solid (``#``) or
passable (``.``), RGB colour (hex) and the approximation category (``full`` when nothing
but the look is simplified).
"""

from __future__ import annotations

# Approximation categories, as the mission-load warning and the docs word them.
CATEGORIES: dict[str, str] = {
    "full": "a plain block",
    "shape": "drawn as a full solid cube (its real shape is not simulated)",
    "passable": "passable, no collision (not climbable)",
    "mechanism": "its mechanism or contents are not simulated",
    "effect": "its effect on the player is not simulated",
}

# Blocks the simulator refuses: drawing them would change the game too much.
REFUSED: dict[str, str] = {
    "fire": "fire spread and burning are not simulated",
    "portal": "nether portals are not simulated",
    "end_portal": "end portals are not simulated",
    "end_gateway": "end gateways are not simulated",
}

_TABLE = """
sapling 0 - hand = . 3c8c28 passable
sponge 0.6 - hand = # c3c350 full
lapis_block 3 pickaxe stone = # 26438a full
dispenser 3.5 pickaxe wood = # 6e6e6e mechanism
sandstone 0.8 pickaxe wood = # d8cb9b full
noteblock 0.8 axe hand = # 64463c mechanism
bed 0.2 - hand = # a02828 shape
golden_rail 0.7 pickaxe hand = . a08c50 passable
detector_rail 0.7 pickaxe hand = . 8c7864 passable
sticky_piston 0.5 - hand = # 8c966e mechanism
web 4 - hand string . dcdcdc effect
tallgrass 0 - hand - . 5a9b3c passable
deadbush 0 - hand - . 94703c passable
piston 0.5 - hand = # 998763 mechanism
piston_head 0.5 - hand - # 998763 mechanism
wool 0.8 - hand = # e9ecec full
piston_extension inf - hand - # 998763 mechanism
yellow_flower 0 - hand = . f0e628 passable
red_flower 0 - hand = . c8281e passable
brown_mushroom 0 - hand = . 966e50 passable
red_mushroom 0 - hand = . c83228 passable
gold_block 3 pickaxe iron = # f6d03d full
iron_block 5 pickaxe stone = # dcdcdc full
double_stone_slab 2 pickaxe wood stone_slab*2 # a8a8a8 full
stone_slab 2 pickaxe wood = # a8a8a8 shape
brick_block 2 pickaxe wood = # 966153 full
tnt 0 - hand = # db441e mechanism
bookshelf 1.5 axe hand book*3 # 6e5537 full
mossy_cobblestone 2 pickaxe wood = # 5a6c5a full
mob_spawner 5 pickaxe wood - # 1e2832 mechanism
oak_stairs 2 axe hand = # a2824e shape
chest 2.5 axe hand = # a0782d mechanism
redstone_wire 0 - hand redstone . aa1e1e passable
diamond_block 5 pickaxe iron = # 62dbd6 full
wheat 0 - hand wheat . c8b450 passable
farmland 0.6 shovel hand dirt # 6e4a2e shape
lit_furnace 3.5 pickaxe wood furnace # 6e6e5a full
standing_sign 1 axe hand sign . a2824e passable
wooden_door 3 axe hand = # a2824e shape
ladder 0.4 axe hand = . 9b7d4b passable
rail 0.7 pickaxe hand = . 8c7864 passable
stone_stairs 2 pickaxe wood = # 646464 shape
wall_sign 1 axe hand sign . a2824e passable
lever 0.5 - hand = . 6e5a46 passable
stone_pressure_plate 0.5 pickaxe wood = . 7d7d7d passable
iron_door 5 pickaxe wood = # c8c8c8 shape
wooden_pressure_plate 0.5 axe hand = . a2824e passable
lit_redstone_ore 3 pickaxe iron redstone*4 # be3232 full
unlit_redstone_torch 0 - hand redstone_torch . 781414 passable
redstone_torch 0 - hand = . dc2828 passable
stone_button 0.5 pickaxe hand = . 7d7d7d passable
snow_layer 0.1 shovel wood snowball . f0fbfb passable
ice 0.5 pickaxe hand - # 91b7fd effect
snow 0.2 shovel wood snowball*4 # f0fbfb full
cactus 0.4 - hand = # 0f7d23 effect
clay 0.6 shovel hand clay_ball*4 # a0a6b3 full
reeds 0 - hand = . 94c065 passable
jukebox 2 axe hand = # 6e4b37 full
fence 2 axe hand = # a2824e shape
pumpkin 1 axe hand = # ce7819 full
netherrack 0.4 pickaxe wood = # 6f3634 full
soul_sand 0.5 shovel hand = # 544033 effect
glowstone 0.3 - hand glowstone_dust*3 # fad782 full
lit_pumpkin 1 axe hand = # e6a03c full
cake 0.5 - hand - # f0e6dc shape
unpowered_repeater 0 - hand repeater . a0a0a0 passable
powered_repeater 0 - hand repeater . b4a0a0 passable
stained_glass 0.3 - hand - # c8c8e6 full
trapdoor 3 axe hand = # a2824e shape
monster_egg 0.75 - hand - # 7d7d7d mechanism
stonebrick 1.5 pickaxe wood = # 7a797a full
brown_mushroom_block 0.2 axe hand brown_mushroom # 8d6a53 full
red_mushroom_block 0.2 axe hand red_mushroom # b6251f full
iron_bars 5 pickaxe wood = # 8c8c8c shape
glass_pane 0.3 - hand - # c8e6eb shape
melon_block 1 axe hand melon*5 # 8caa28 full
pumpkin_stem 0 - hand - . 6e9628 passable
melon_stem 0 - hand - . 6e9628 passable
vine 0.2 - hand - . 326e1e passable
fence_gate 2 axe hand = # a2824e shape
brick_stairs 2 pickaxe wood = # 966153 shape
stone_brick_stairs 1.5 pickaxe wood = # 7a797a shape
mycelium 0.6 shovel hand dirt # 6f6369 full
waterlily 0 - hand = . 207830 passable
nether_brick 2 pickaxe wood = # 2d161a full
nether_brick_fence 2 pickaxe wood = # 2d161a shape
nether_brick_stairs 2 pickaxe wood = # 2d161a shape
nether_wart 0 - hand = . 962828 passable
enchanting_table 5 pickaxe wood = # 3c283c shape
brewing_stand 0.5 pickaxe wood = # 7d6e50 shape
cauldron 2 pickaxe wood = # 3c3c3c shape
end_portal_frame inf - hand - # 376e5a mechanism
end_stone 3 pickaxe wood = # dbde9e full
dragon_egg 3 - hand = # 0c0910 mechanism
redstone_lamp 0.3 - hand = # 8c5a32 full
lit_redstone_lamp 0.3 - hand redstone_lamp # d2a064 full
double_wooden_slab 2 axe hand wooden_slab*2 # a2824e full
wooden_slab 2 axe hand = # a2824e shape
cocoa 0.2 axe hand dye . 96643c passable
sandstone_stairs 0.8 pickaxe wood = # d8cb9b shape
emerald_ore 3 pickaxe iron emerald # 64a06e full
ender_chest 22.5 pickaxe wood obsidian*8 # 283c3c mechanism
tripwire_hook 0 - hand = . 8c8c8c passable
tripwire 0 - hand string . dcdcdc passable
emerald_block 5 pickaxe iron = # 51d975 full
spruce_stairs 2 axe hand = # 68502f shape
birch_stairs 2 axe hand = # c4b37b shape
jungle_stairs 2 axe hand = # a0734f shape
command_block inf - hand - # b48c64 mechanism
beacon 3 - hand = # 8cdcdc mechanism
cobblestone_wall 2 pickaxe wood = # 646464 shape
flower_pot 0 - hand = . 7c4536 passable
carrots 0 - hand carrot . 3ca028 passable
potatoes 0 - hand potato . 3ca028 passable
wooden_button 0.5 - hand = . a2824e passable
skull 1 - hand = # c8c8b4 shape
anvil 5 pickaxe wood = # 464646 shape
trapped_chest 2.5 axe hand = # a0782d mechanism
light_weighted_pressure_plate 0.5 pickaxe wood = . f6d03d passable
heavy_weighted_pressure_plate 0.5 pickaxe wood = . dcdcdc passable
unpowered_comparator 0 - hand comparator . a0a0a0 passable
powered_comparator 0 - hand comparator . b4a0a0 passable
daylight_detector 0.2 axe hand = # 8c7d64 shape
redstone_block 5 pickaxe wood = # af1805 full
quartz_ore 3 pickaxe wood quartz # 7d5550 full
hopper 3 pickaxe wood = # 464646 mechanism
quartz_block 0.8 pickaxe wood = # ece9e2 full
quartz_stairs 0.8 pickaxe wood = # ece9e2 shape
activator_rail 0.7 pickaxe hand = . 8c6464 passable
dropper 3.5 pickaxe wood = # 6e6e6e mechanism
stained_hardened_clay 1.25 pickaxe wood = # a0786e full
stained_glass_pane 0.3 - hand - # c8c8e6 shape
leaves2 0.2 - hand - # 3c6e1e full
log2 2 axe hand = # 5a4632 full
acacia_stairs 2 axe hand = # a85a32 shape
dark_oak_stairs 2 axe hand = # 42291a shape
slime 0 - hand = # 78c864 effect
barrier inf - hand - # 000000 effect
iron_trapdoor 5 pickaxe wood = # c8c8c8 shape
prismarine 1.5 pickaxe wood = # 63a091 full
sea_lantern 0.3 - hand prismarine_crystals*2 # aac8be full
hay_block 0.5 - hand = # a68826 full
carpet 0.1 - hand = . e9ecec passable
hardened_clay 1.25 pickaxe wood = # 965c42 full
coal_block 5 pickaxe wood = # 141414 full
packed_ice 0.5 pickaxe hand - # a0befa effect
double_plant 0 - hand - . 5a9b3c passable
standing_banner 1 axe hand banner . e9ecec passable
wall_banner 1 axe hand banner . e9ecec passable
daylight_detector_inverted 0.2 axe hand daylight_detector # 8c7d64 shape
red_sandstone 0.8 pickaxe wood = # ba631d full
red_sandstone_stairs 0.8 pickaxe wood = # ba631d shape
double_stone_slab2 2 pickaxe wood stone_slab2*2 # ba631d full
stone_slab2 2 pickaxe wood = # ba631d shape
spruce_fence_gate 2 axe hand = # 68502f shape
birch_fence_gate 2 axe hand = # c4b37b shape
jungle_fence_gate 2 axe hand = # a0734f shape
dark_oak_fence_gate 2 axe hand = # 42291a shape
acacia_fence_gate 2 axe hand = # a85a32 shape
spruce_fence 2 axe hand = # 68502f shape
birch_fence 2 axe hand = # c4b37b shape
jungle_fence 2 axe hand = # a0734f shape
dark_oak_fence 2 axe hand = # 42291a shape
acacia_fence 2 axe hand = # a85a32 shape
spruce_door 3 axe hand = # 68502f shape
birch_door 3 axe hand = # c4b37b shape
jungle_door 3 axe hand = # a0734f shape
acacia_door 3 axe hand = # a85a32 shape
dark_oak_door 3 axe hand = # 42291a shape
end_rod 0 - hand = . f0f0f0 passable
chorus_plant 0.4 axe hand chorus_fruit # 5a3c5a shape
chorus_flower 0.4 axe hand - # 8c6e8c shape
purpur_block 1.5 pickaxe wood = # a97da9 full
purpur_pillar 1.5 pickaxe wood = # ab81ab full
purpur_stairs 1.5 pickaxe wood = # a97da9 shape
purpur_double_slab 2 pickaxe wood purpur_slab*2 # a97da9 full
purpur_slab 2 pickaxe wood = # a97da9 shape
end_bricks 0.8 pickaxe wood = # dbe0a2 full
beetroots 0 - hand beetroot . 3ca028 passable
grass_path 0.65 shovel hand dirt # 947a41 shape
repeating_command_block inf - hand - # 7864b4 mechanism
chain_command_block inf - hand - # 64b48c mechanism
frosted_ice 0.5 - hand - # 91b7fd effect
magma 0.5 pickaxe wood = # 8c3c14 effect
nether_wart_block 1 - hand = # 731010 full
red_nether_brick 2 pickaxe wood = # 460709 full
bone_block 2 pickaxe wood = # e5e1cf full
structure_void 0 - hand - . 000000 passable
observer 3.5 pickaxe wood = # 646464 mechanism
white_shulker_box 2 pickaxe hand = # e6e6e6 mechanism
orange_shulker_box 2 pickaxe hand = # e6781e mechanism
magenta_shulker_box 2 pickaxe hand = # be46b4 mechanism
light_blue_shulker_box 2 pickaxe hand = # 6496d2 mechanism
yellow_shulker_box 2 pickaxe hand = # e6c832 mechanism
lime_shulker_box 2 pickaxe hand = # 78be28 mechanism
pink_shulker_box 2 pickaxe hand = # e696aa mechanism
gray_shulker_box 2 pickaxe hand = # 464646 mechanism
silver_shulker_box 2 pickaxe hand = # 969696 mechanism
cyan_shulker_box 2 pickaxe hand = # 288c96 mechanism
purple_shulker_box 2 pickaxe hand = # 783ca0 mechanism
blue_shulker_box 2 pickaxe hand = # 323c96 mechanism
brown_shulker_box 2 pickaxe hand = # 6e4628 mechanism
green_shulker_box 2 pickaxe hand = # 465a1e mechanism
red_shulker_box 2 pickaxe hand = # a0281e mechanism
black_shulker_box 2 pickaxe hand = # 1e1e1e mechanism
structure_block inf - hand - # 645a6e mechanism
"""


def rows() -> list[tuple[str, float, str, str, str, int, bool, tuple[int, int, int], str]]:
    """The table as (name, hardness, tool, level, drop, drop count, solid, colour, category)."""
    out = []
    for line in _TABLE.strip().splitlines():
        name, hardness, tool, level, drop, solid, colour, category = line.split()
        count = 1
        if drop == "=":
            drop = name
        elif drop == "-":
            drop, count = "", 0
        elif "*" in drop:
            drop, n = drop.split("*")
            count = int(n)
        rgb = (int(colour[0:2], 16), int(colour[2:4], 16), int(colour[4:6], 16))
        tool = "" if tool == "-" else tool
        out.append((name, float(hardness), tool, level, drop, count, solid == "#", rgb, category))
    return out


NOTES: dict[str, str] = {r[0]: r[8] for r in rows() if r[8] != "full"}
