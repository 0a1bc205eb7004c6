"""The proxy scene's classes, written by us.

Each class has "appearance" names (what the voxels are built from: they stand in for the
visual evidence an image encoder sees) and separate "language" names (what the taxonomy
YAML offers the ``taxonomy`` heuristic). The two sets are disjoint over the whole table,
so no method ever embeds the exact strings that built the map.

``place`` says where instances go: ``structure`` (floor, wall, ceiling), ``floor``
(stands on the floor), ``wall`` (thin, on a wall), ``top`` (on a table, desk, counter,
cabinet or shelf). ``size`` is the box (x, y, z) in metres before a random +-20 % jitter.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SceneClass:
    label: str
    appearance: tuple[str, ...]
    language: tuple[str, ...]
    color: tuple[int, int, int]
    place: str
    size: tuple[float, float, float] = (0.5, 0.5, 0.5)


def _c(label, appearance, language, color, place, size=(0.5, 0.5, 0.5)) -> SceneClass:
    return SceneClass(label, tuple(appearance), tuple(language), tuple(color), place, size)


CLASSES: tuple[SceneClass, ...] = (
    _c(
        "floor",
        ["wooden floorboards", "tiled floor", "parquet flooring", "laminate floor"],
        ["ground", "flooring", "floor surface", "linoleum", "floor tiles"],
        (150, 120, 90),
        "structure",
    ),
    _c(
        "wall",
        ["painted wall", "plaster wall", "white wall", "brick wall", "wallpapered wall"],
        ["partition", "drywall", "interior wall", "wall panel", "room divider"],
        (220, 215, 200),
        "structure",
    ),
    _c(
        "ceiling",
        ["white ceiling", "plaster ceiling", "suspended ceiling", "ceiling panel"],
        ["overhead", "roof", "ceiling tile", "soffit", "ceiling board"],
        (240, 240, 235),
        "structure",
    ),
    _c(
        "door",
        ["wooden door", "white door", "panel door", "interior door"],
        ["doorway", "entrance", "front door", "sliding door", "gate"],
        (120, 80, 40),
        "wall",
        (0.9, 0.06, 2.0),
    ),
    _c(
        "window",
        ["glass window", "window pane", "sash window", "window frame"],
        ["bay window", "skylight", "casement", "glazing", "window glass"],
        (150, 200, 230),
        "wall",
        (1.2, 0.06, 1.1),
    ),
    _c(
        "chair",
        ["office chair", "dining chair", "wooden chair", "armchair"],
        ["seat", "desk chair", "folding chair", "rocking chair", "swivel chair", "high chair"],
        (200, 60, 60),
        "floor",
        (0.5, 0.5, 0.9),
    ),
    _c(
        "table",
        ["dining table", "wooden table", "coffee table", "kitchen table"],
        ["side table", "end table", "folding table", "round table", "tabletop"],
        (160, 100, 50),
        "floor",
        (1.4, 0.8, 0.75),
    ),
    _c(
        "sofa",
        ["couch", "fabric sofa", "leather sofa", "sectional sofa"],
        ["settee", "loveseat", "divan", "futon", "chesterfield"],
        (90, 90, 160),
        "floor",
        (2.0, 0.9, 0.85),
    ),
    _c(
        "bed",
        ["double bed", "single bed", "bed with pillows", "mattress"],
        ["bunk bed", "cot", "bedstead", "queen bed", "daybed"],
        (230, 200, 200),
        "floor",
        (2.0, 1.5, 0.6),
    ),
    _c(
        "cabinet",
        ["wooden cabinet", "kitchen cabinet", "storage cabinet", "cupboard"],
        ["closet", "wardrobe", "chest of drawers", "dresser", "sideboard"],
        (130, 90, 60),
        "floor",
        (1.0, 0.5, 1.2),
    ),
    _c(
        "shelf",
        ["bookshelf", "wall shelf", "shelving unit", "bookcase"],
        ["shelves", "storage rack", "ledge", "display shelf", "shelf unit"],
        (170, 130, 80),
        "floor",
        (1.0, 0.35, 1.8),
    ),
    _c(
        "desk",
        ["office desk", "writing desk", "computer desk", "work desk"],
        ["workstation", "bureau", "secretary desk", "standing desk", "study table"],
        (110, 70, 40),
        "floor",
        (1.2, 0.7, 0.75),
    ),
    _c(
        "plant",
        ["potted plant", "houseplant", "green leaves", "ficus"],
        ["flowerpot", "fern", "succulent", "shrub", "foliage"],
        (40, 160, 60),
        "floor",
        (0.5, 0.5, 1.0),
    ),
    _c(
        "lamp",
        ["floor lamp", "table lamp", "lampshade", "desk lamp"],
        ["light fixture", "lantern", "reading light", "torchiere", "light bulb"],
        (250, 220, 100),
        "floor",
        (0.4, 0.4, 1.5),
    ),
    _c(
        "tv",
        ["television", "flat screen tv", "tv screen", "television set"],
        ["telly", "display screen", "smart tv", "plasma screen", "television receiver"],
        (30, 30, 30),
        "wall",
        (1.2, 0.08, 0.7),
    ),
    _c(
        "picture",
        ["framed picture", "painting", "wall art", "photo frame"],
        ["artwork", "canvas", "poster", "portrait", "art print"],
        (200, 150, 220),
        "wall",
        (0.8, 0.05, 0.6),
    ),
    _c(
        "mirror",
        ["wall mirror", "bathroom mirror", "full length mirror", "looking glass"],
        ["vanity mirror", "reflective glass", "hand mirror", "mirror frame", "dressing mirror"],
        (190, 220, 220),
        "wall",
        (0.6, 0.05, 0.9),
    ),
    _c(
        "sink",
        ["kitchen sink", "bathroom sink", "washbasin", "basin"],
        ["lavatory basin", "vanity sink", "faucet", "wash bowl", "utility sink"],
        (200, 200, 210),
        "floor",
        (0.6, 0.5, 0.9),
    ),
    _c(
        "toilet",
        ["toilet bowl", "toilet seat", "water closet", "commode"],
        ["lavatory", "loo", "flush toilet", "restroom fixture", "urinal"],
        (245, 245, 250),
        "floor",
        (0.4, 0.65, 0.8),
    ),
    _c(
        "refrigerator",
        ["fridge", "refrigerator door", "freezer", "steel fridge"],
        ["icebox", "cooler", "fridge freezer", "chiller", "minibar"],
        (210, 210, 220),
        "floor",
        (0.7, 0.7, 1.8),
    ),
    _c(
        "stove",
        ["kitchen stove", "gas cooker", "oven", "cooktop"],
        ["range", "hob", "burner", "hotplate", "stovetop"],
        (80, 80, 80),
        "floor",
        (0.6, 0.6, 0.9),
    ),
    _c(
        "curtain",
        ["window curtain", "drapes", "fabric curtain", "blinds"],
        ["drapery", "curtain panel", "window shade", "valance", "shower curtain"],
        (180, 60, 120),
        "wall",
        (1.4, 0.08, 2.0),
    ),
    _c(
        "cushion",
        ["pillow", "throw pillow", "sofa cushion", "bolster"],
        ["seat cushion", "headrest", "pouf", "floor cushion", "pillowcase"],
        (240, 160, 60),
        "top",
        (0.45, 0.45, 0.2),
    ),
    _c(
        "towel",
        ["bath towel", "hand towel", "hanging towel", "folded towel"],
        ["washcloth", "flannel", "tea towel", "beach towel", "dish cloth"],
        (100, 200, 200),
        "wall",
        (0.5, 0.06, 0.7),
    ),
    _c(
        "clock",
        ["wall clock", "analog clock", "clock face", "alarm clock"],
        ["timepiece", "timer", "wristwatch", "cuckoo clock", "chronometer"],
        (250, 250, 250),
        "wall",
        (0.35, 0.05, 0.35),
    ),
    _c(
        "book",
        ["hardcover book", "stack of books", "paperback", "novel"],
        ["textbook", "volume", "notebook", "magazine", "encyclopedia"],
        (60, 100, 200),
        "top",
        (0.3, 0.22, 0.15),
    ),
    _c(
        "vase",
        ["flower vase", "glass vase", "ceramic vase", "urn"],
        ["jar", "vessel", "pot", "amphora", "jug"],
        (100, 180, 250),
        "top",
        (0.2, 0.2, 0.35),
    ),
    _c(
        "trash can",
        ["waste bin", "garbage bin", "rubbish bin", "wastebasket"],
        ["dustbin", "litter bin", "recycling bin", "trash bin", "garbage can"],
        (90, 110, 90),
        "floor",
        (0.35, 0.35, 0.5),
    ),
    _c(
        "radiator",
        ["wall radiator", "wall heater", "heating radiator", "space heater"],
        ["heater", "heating panel", "convector", "baseboard heater", "central heating"],
        (230, 230, 230),
        "wall",
        (1.0, 0.1, 0.6),
    ),
    _c(
        "counter",
        ["kitchen counter", "countertop", "worktop", "kitchen island"],
        ["bar counter", "counter top", "work surface", "benchtop", "service counter"],
        (170, 170, 150),
        "floor",
        (1.8, 0.6, 0.9),
    ),
    _c(
        "laptop",
        ["silver laptop", "computer keyboard", "desktop computer", "open laptop"],
        ["notebook computer", "pc", "personal computer", "netbook", "computer"],
        (50, 50, 60),
        "top",
        (0.35, 0.25, 0.05),
    ),
    _c(
        "rug",
        ["area rug", "carpet rug", "doormat", "floor mat"],
        ["runner", "mat", "kilim", "bath mat", "carpet"],
        (160, 40, 40),
        "floor",
        (1.6, 1.1, 0.02),
    ),
)

#: Classes that only the taxonomy knows: the default absence queries.
ABSENT: dict[str, tuple[str, ...]] = {
    "piano": ("grand piano", "upright piano", "keyboard instrument", "pianoforte"),
    "bathtub": ("bath", "tub", "jacuzzi", "hot tub", "soaking tub"),
    "fireplace": ("hearth", "mantelpiece", "wood stove", "chimney"),
    "bicycle": ("bike", "cycle", "mountain bike", "tandem"),
    "washing machine": ("washer", "laundry machine", "tumble dryer", "clothes washer"),
}

#: Free-text absence queries that no class covers.
ABSENT_FREE_TEXT = ("a red sports car", "an elephant")

SUPPORTS = ("table", "desk", "counter", "cabinet", "shelf", "sofa", "bed")

#: Free-text descriptions of the labels: open-vocabulary queries whose ground truth is
#: the label (``SCENE.open-queries.yaml``).
FREE_TEXT_A: dict[str, str] = {
    "chair": "something to sit on at a desk",
    "table": "something to put a plate on",
    "sofa": "where to lounge and watch a film",
    "bed": "somewhere to sleep",
    "cabinet": "where to store dishes",
    "shelf": "where books are stored",
    "desk": "where to do homework",
    "plant": "something green that needs watering",
    "lamp": "something that lights up the room",
    "tv": "a screen to watch the news",
    "picture": "art hanging on the wall",
    "mirror": "where I can see my reflection",
    "sink": "where to wash my hands",
    "toilet": "where to pee",
    "refrigerator": "where the milk is kept cold",
    "stove": "where to cook a meal",
    "curtain": "fabric that covers the window",
    "cushion": "something soft to lean on",
    "towel": "something to dry myself with",
    "clock": "something that tells the time",
    "book": "something to read",
    "vase": "something to put flowers in",
    "trash can": "where to throw rubbish away",
    "radiator": "something that heats the room",
    "counter": "where to chop vegetables",
    "laptop": "something to type emails on",
    "rug": "something soft on the floor",
}
#: Absent free text of the open-vocabulary query file (nothing in any scene is one).
ABSENT_FREE_TEXT_OPEN = (
    "a red sports car",
    "an elephant",
    "somewhere to park a boat",
    "a grand piano",
    "where to take a bubble bath",
)


def check_disjoint() -> None:
    """Raise ValueError when an appearance name is also a language or label name."""
    from .class_file import shared_names

    both = shared_names(CLASSES, ABSENT)
    if both:
        raise ValueError(f"appearance and language names overlap: {[n for n, _ in both]}")
