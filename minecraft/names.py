"""Minecraft 1.11 names that Malmo's mission schema accepts: block, item and entity types,
and the small enumerations (colours, facings, variants) their attributes may take.

These are Minecraft's own registry names (the ones ``/give`` and ``/setblock`` use), in
the spelling and order Malmo's ``Types.xsd`` enumerates them. The mission schema check
(``minecraft.malmo.schema``) refuses any other name, as Malmo does; the simulator
(``minecraft.blocks``) has an entry for every block type listed here.
"""

from __future__ import annotations

# Block types in numeric-id order (air = 0 ... black_shulker_box = 234; structure_block is 255).
BLOCK_TYPES: tuple[str, ...] = tuple(
    """
    air stone grass dirt cobblestone planks sapling bedrock flowing_water water
    flowing_lava lava sand gravel gold_ore iron_ore coal_ore log leaves sponge glass
    lapis_ore lapis_block dispenser sandstone noteblock bed golden_rail detector_rail
    sticky_piston web tallgrass deadbush piston piston_head wool piston_extension
    yellow_flower red_flower brown_mushroom red_mushroom gold_block iron_block
    double_stone_slab stone_slab brick_block tnt bookshelf mossy_cobblestone obsidian
    torch fire mob_spawner oak_stairs chest redstone_wire diamond_ore diamond_block
    crafting_table wheat farmland furnace lit_furnace standing_sign wooden_door ladder
    rail stone_stairs wall_sign lever stone_pressure_plate iron_door
    wooden_pressure_plate redstone_ore lit_redstone_ore unlit_redstone_torch
    redstone_torch stone_button snow_layer ice snow cactus clay reeds jukebox fence
    pumpkin netherrack soul_sand glowstone portal lit_pumpkin cake unpowered_repeater
    powered_repeater stained_glass trapdoor monster_egg stonebrick brown_mushroom_block
    red_mushroom_block iron_bars glass_pane melon_block pumpkin_stem melon_stem vine
    fence_gate brick_stairs stone_brick_stairs mycelium waterlily nether_brick
    nether_brick_fence nether_brick_stairs nether_wart enchanting_table brewing_stand
    cauldron end_portal end_portal_frame end_stone dragon_egg redstone_lamp
    lit_redstone_lamp double_wooden_slab wooden_slab cocoa sandstone_stairs emerald_ore
    ender_chest tripwire_hook tripwire emerald_block spruce_stairs birch_stairs
    jungle_stairs command_block beacon cobblestone_wall flower_pot carrots potatoes
    wooden_button skull anvil trapped_chest light_weighted_pressure_plate
    heavy_weighted_pressure_plate unpowered_comparator powered_comparator
    daylight_detector redstone_block quartz_ore hopper quartz_block quartz_stairs
    activator_rail dropper stained_hardened_clay stained_glass_pane leaves2 log2
    acacia_stairs dark_oak_stairs slime barrier iron_trapdoor prismarine sea_lantern
    hay_block carpet hardened_clay coal_block packed_ice double_plant standing_banner
    wall_banner daylight_detector_inverted red_sandstone red_sandstone_stairs
    double_stone_slab2 stone_slab2 spruce_fence_gate birch_fence_gate jungle_fence_gate
    dark_oak_fence_gate acacia_fence_gate spruce_fence birch_fence jungle_fence
    dark_oak_fence acacia_fence spruce_door birch_door jungle_door acacia_door
    dark_oak_door end_rod chorus_plant chorus_flower purpur_block purpur_pillar
    purpur_stairs purpur_double_slab purpur_slab end_bricks beetroots grass_path
    end_gateway repeating_command_block chain_command_block frosted_ice magma
    nether_wart_block red_nether_brick bone_block structure_void observer
    white_shulker_box orange_shulker_box magenta_shulker_box light_blue_shulker_box
    yellow_shulker_box lime_shulker_box pink_shulker_box gray_shulker_box
    silver_shulker_box cyan_shulker_box purple_shulker_box blue_shulker_box
    brown_shulker_box green_shulker_box red_shulker_box black_shulker_box
    structure_block
    """.split()
)

# Item types that are not blocks (a block's item has the block's name).
ITEM_TYPES: frozenset[str] = frozenset(
    """
    iron_shovel iron_pickaxe iron_axe flint_and_steel apple bow arrow coal diamond
    iron_ingot gold_ingot iron_sword wooden_sword wooden_shovel wooden_pickaxe
    wooden_axe stone_sword stone_shovel stone_pickaxe stone_axe diamond_sword
    diamond_shovel diamond_pickaxe diamond_axe stick bowl mushroom_stew golden_sword
    golden_shovel golden_pickaxe golden_axe string feather gunpowder wooden_hoe
    stone_hoe iron_hoe diamond_hoe golden_hoe wheat_seeds wheat bread leather_helmet
    leather_chestplate leather_leggings leather_boots chainmail_helmet
    chainmail_chestplate chainmail_leggings chainmail_boots iron_helmet iron_chestplate
    iron_leggings iron_boots diamond_helmet diamond_chestplate diamond_leggings
    diamond_boots golden_helmet golden_chestplate golden_leggings golden_boots flint
    porkchop cooked_porkchop painting golden_apple sign wooden_door bucket water_bucket
    lava_bucket minecart saddle iron_door redstone snowball boat leather milk_bucket
    brick clay_ball reeds paper book slime_ball chest_minecart furnace_minecart egg
    compass fishing_rod clock glowstone_dust fish cooked_fish dye bone sugar cake bed
    repeater cookie filled_map shears melon pumpkin_seeds melon_seeds beef cooked_beef
    chicken cooked_chicken rotten_flesh ender_pearl blaze_rod ghast_tear gold_nugget
    nether_wart potion glass_bottle spider_eye fermented_spider_eye blaze_powder
    magma_cream brewing_stand cauldron ender_eye speckled_melon spawn_egg
    experience_bottle fire_charge writable_book written_book emerald item_frame
    flower_pot carrot potato baked_potato poisonous_potato map golden_carrot skull
    carrot_on_a_stick nether_star pumpkin_pie fireworks firework_charge enchanted_book
    comparator netherbrick quartz tnt_minecart hopper_minecart prismarine_shard
    prismarine_crystals rabbit cooked_rabbit rabbit_stew rabbit_foot rabbit_hide
    armor_stand iron_horse_armor golden_horse_armor diamond_horse_armor lead name_tag
    command_block_minecart mutton cooked_mutton banner spruce_door birch_door
    jungle_door acacia_door dark_oak_door chorus_fruit chorus_fruit_popped beetroot
    beetroot_seeds beetroot_soup dragon_breath splash_potion spectral_arrow tipped_arrow
    lingering_potion shield elytra spruce_boat birch_boat jungle_boat acacia_boat
    dark_oak_boat totem_of_undying shulker_shell iron_nugget record_13 record_cat
    record_blocks record_chirp record_far record_mall record_mellohi record_stal
    record_strad record_ward record_11 record_wait
    """.split()
)

# Mobs and animals (Minecraft 1.11 entity names, as Malmo spells them).
LIVING_ENTITY_TYPES: frozenset[str] = frozenset(
    """
    ElderGuardian WitherSkeleton Stray Husk ZombieVillager SkeletonHorse ZombieHorse
    EvocationIllager VindicationIllager Vex Creeper Skeleton Spider Giant Zombie Slime
    Ghast PigZombie Enderman CaveSpider Silverfish Blaze LavaSlime EnderDragon
    WitherBoss Bat Witch Endermite Guardian Shulker Donkey Mule Pig Sheep Cow Chicken
    Squid Wolf MushroomCow SnowMan Ozelot VillagerGolem Horse Rabbit PolarBear Llama
    Villager
    """.split()
)

# Entities that are not alive but can be spawned with DrawEntity.
OTHER_ENTITY_TYPES: frozenset[str] = frozenset(
    """
    MinecartRideable MinecartChest MinecartFurnace MinecartTNT MinecartSpawner
    MinecartHopper MinecartCommandBlock Boat ArmorStand ItemFrame EnderCrystal LeashKnot
    Painting PrimedTnt FallingSand
    """.split()
)

SPAWNABLE_TYPES: frozenset[str] = LIVING_ENTITY_TYPES | OTHER_ENTITY_TYPES
BLOCK_OR_ITEM_TYPES: frozenset[str] = frozenset(BLOCK_TYPES) | ITEM_TYPES

COLOURS: frozenset[str] = frozenset(
    "WHITE ORANGE MAGENTA LIGHT_BLUE YELLOW LIME PINK GRAY SILVER CYAN PURPLE BLUE BROWN "
    "GREEN RED BLACK".split()
)
FACINGS: frozenset[str] = frozenset("DOWN UP NORTH SOUTH WEST EAST UP_X DOWN_X UP_Z DOWN_Z".split())
# Variation: stone, wood and flower kinds, entity names (spawn eggs), rail shapes, monster
# egg kinds, halves and note-block notes.
VARIANTS: frozenset[str] = LIVING_ENTITY_TYPES | frozenset(
    """
    stone granite smooth_granite diorite smooth_diorite andesite smooth_andesite
    oak spruce birch jungle acacia dark_oak
    dandelion poppy blue_orchid allium houstonia red_tulip orange_tulip white_tulip
    pink_tulip oxeye_daisy
    north_south east_west north_east north_west south_east south_west ascending_east
    ascending_west ascending_north ascending_south
    cobblestone stone_brick mossy_brick cracked_brick chiseled_brick
    top bottom head foot upper lower
    F_sharp_3 G3 G_sharp_3 A3 A_sharp_3 B3 C4 C_sharp_4 D4 D_sharp_4 E4 F4 F_sharp_4 G4
    G_sharp_4 A4 A_sharp_4 B4 C5 C_sharp_5 D5 D_sharp_5 E5 F5 F_sharp_5
    """.split()
)
CONTAINER_TYPES: frozenset[str] = frozenset(
    "dispenser chest trapped_chest hopper dropper".split()
    + [b for b in BLOCK_TYPES if b.endswith("_shulker_box")]
)
SIGN_TYPES: frozenset[str] = frozenset(("standing_sign", "wall_sign"))


def numeric_id(block: str) -> int:
    """Minecraft's numeric id of a block type (``structure_block`` is 255)."""
    return 255 if block == "structure_block" else BLOCK_TYPES.index(block)
