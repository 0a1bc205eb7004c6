"""A second class table for the proxy scene: other labels, other names, no shared word.

``quash make-scene --classes b`` builds from it. It stands in for a held-out map built
like the project's scenes "from another taxonomy and other names": a Matterport-like
label set (stool, chest of drawers, tv monitor, shower, bathtub, fireplace, lighting,
shelving, blinds, column, railing, stairs, gym equipment, clothes, board panel...), five
room types (one a gym), and rules stricter than table A's (:mod:`.classes`):

- no **word** of any appearance name occurs in any language name or label of the table
  (table A only keeps whole strings apart: "office chair" builds voxels, "desk chair" is
  a language name). MiniLM is a lexical sentence encoder: a shared word gives it a
  string-matching shortcut no image encoder offers. Four classes
  (:data:`HEAD_WORD_ALLOWED`) may use their label's own head word, because MiniLM
  recognised no word-free description of them;
- no appearance name is in the shipped ``vocabulary.txt`` (table A: 51 of 129 are), so
  the offline ``vocabulary`` heuristic never embeds a string that built the map;
- every class is still recognisable: the noiseless mean of a class's appearance names is
  nearest (label and sub-classes, top-2 mean of cosines, MiniLM) to its own label
  (``tests/demo/test_scene.py`` checks it with MiniLM).

Appearance names are short visual descriptions ("four-legged perch with a backrest")
rather than the category's noun: they stand in for what an image encoder sees.
:func:`check_b` enforces the word and vocabulary rules.
"""

from __future__ import annotations

import re

from .classes import SceneClass, _c

CLASSES_B: tuple[SceneClass, ...] = (
    _c(
        "floor",
        [
            "polished hardwood planks",
            "grey concrete slab underfoot",
            "herringbone parquet underfoot",
            "terrazzo underfoot",
        ],
        ["ground", "flooring", "floorboards", "floor tiles", "vinyl flooring"],
        (150, 120, 90),
        "structure",
    ),
    _c(
        "wall",
        ["painted plasterboard", "whitewashed masonry", "textured stucco", "exposed brickwork"],
        ["partition", "drywall", "interior wall", "wainscoting", "room divider"],
        (220, 215, 200),
        "structure",
    ),
    _c(
        "ceiling",
        ["overhead plaster", "vaulted overhead", "cornice and coving", "overhead beams"],
        ["roof", "ceiling tile", "soffit", "drop ceiling", "ceiling board"],
        (240, 240, 235),
        "structure",
    ),
    _c(
        "door",
        ["entryway with a knob", "hinged wooden entry", "portal with hinges and a latch"],
        ["doorway", "front door", "sliding door", "french door", "gate"],
        (120, 80, 40),
        "wall",
        (0.9, 0.06, 2.0),
    ),
    _c(
        "window",
        ["glazed sash", "panes of glass letting in daylight", "sash window with mullions"],
        ["bay window", "skylight", "casement", "dormer", "porthole"],
        (150, 200, 230),
        "wall",
        (1.2, 0.06, 1.1),
    ),
    _c(
        "chair",
        ["seat with a backrest and four legs", "wooden seat with a back", "swivelling office seat"],
        ["desk chair", "folding chair", "rocking chair", "dining chair", "armchair", "high chair"],
        (200, 60, 60),
        "floor",
        (0.5, 0.5, 0.9),
    ),
    _c(
        "stool",
        ["backless seat", "tall stool with a footrest", "milking stool", "round backless seat"],
        ["bar stool", "step stool", "footstool", "counter stool", "ottoman"],
        (210, 90, 40),
        "floor",
        (0.4, 0.4, 0.7),
    ),
    _c(
        "table",
        ["refectory table", "trestle table", "dinette", "four-legged flat-topped furniture"],
        ["side table", "coffee table", "end table", "dining table", "card table"],
        (160, 100, 50),
        "floor",
        (1.4, 0.8, 0.75),
    ),
    _c(
        "sofa",
        ["upholstered three-seater", "davenport", "long upholstered lounge"],
        ["couch", "settee", "loveseat", "futon", "chesterfield", "sectional"],
        (90, 90, 160),
        "floor",
        (2.0, 0.9, 0.85),
    ),
    _c(
        "bed",
        [
            "mattress on a frame with a headboard",
            "quilted duvet and headboard",
            "made-up sleeping platform",
        ],
        ["bunk bed", "cot", "bedstead", "queen bed", "daybed", "double bed"],
        (230, 200, 200),
        "floor",
        (2.0, 1.5, 0.6),
    ),
    _c(
        "chest of drawers",
        [
            "stack of pull-out compartments",
            "highboy",
            "bedroom furniture with pull-out compartments",
        ],
        ["dresser", "bureau", "tallboy", "nightstand", "lowboy"],
        (140, 100, 70),
        "floor",
        (0.9, 0.5, 1.0),
    ),
    _c(
        "cabinet",
        [
            "closed compartment with hinged leaves",
            "built-in pantry",
            "lacquered box with lids on a plinth",
        ],
        ["closet", "wardrobe", "sideboard", "cupboard", "armoire", "credenza"],
        (130, 90, 60),
        "floor",
        (1.0, 0.5, 1.2),
    ),
    _c(
        "shelving",
        [
            "open tiers of planks on brackets",
            "stacked horizontal planks holding paperbacks",
            "metal wire tiers",
        ],
        ["bookshelf", "bookcase", "shelves", "storage rack", "shelf unit"],
        (170, 130, 80),
        "floor",
        (1.0, 0.35, 1.8),
    ),
    _c(
        "plant",
        ["leafy green fronds in a planter", "potted greenery", "trailing ivy in terracotta"],
        ["houseplant", "fern", "succulent", "shrub", "flowerpot", "cactus"],
        (40, 160, 60),
        "floor",
        (0.5, 0.5, 1.0),
    ),
    _c(
        "lighting",
        ["glowing bulb under a fabric hood", "pendant luminaire", "illuminated frosted globe"],
        ["lamp", "chandelier", "floor lamp", "sconce", "ceiling light", "desk lamp"],
        (250, 220, 100),
        "floor",
        (0.4, 0.4, 1.5),
    ),
    _c(
        "tv monitor",
        ["dark rectangular flatscreen", "glossy widescreen display", "hung lcd slab"],
        ["television", "tv", "monitor", "computer screen", "smart tv", "telly"],
        (30, 30, 30),
        "wall",
        (1.2, 0.08, 0.7),
    ),
    _c(
        "picture",
        ["framed oil canvas", "framed landscape", "framed watercolour", "oil canvas"],
        ["painting", "poster", "photograph", "portrait", "artwork", "art print"],
        (200, 150, 220),
        "wall",
        (0.8, 0.05, 0.6),
    ),
    _c(
        "mirror",
        ["reflective silvered pane", "bevelled looking-glass", "polished reflecting oval"],
        ["vanity mirror", "wall mirror", "hand mirror", "dressing mirror", "cheval"],
        (190, 220, 220),
        "wall",
        (0.6, 0.05, 0.9),
    ),
    _c(
        "curtain",
        ["long hanging velvet folds", "sheer voile on a rod", "pleated textile hangings"],
        ["drapes", "drapery", "valance", "curtain panel", "shower curtain"],
        (180, 60, 120),
        "wall",
        (1.4, 0.08, 2.0),
    ),
    _c(
        "blinds",
        [
            "horizontal slats over a pane",
            "louvred slats over a pane",
            "slatted sunscreen over glazing",
        ],
        ["window shade", "roller blind", "venetian blind", "shutter", "jalousie"],
        (200, 200, 170),
        "wall",
        (1.2, 0.06, 1.2),
    ),
    _c(
        "cushion",
        ["plump stuffed fabric square", "tasselled decorative square", "cylindrical padded roll"],
        ["pillow", "throw pillow", "scatter cushion", "pouf", "bolster", "floor cushion"],
        (240, 160, 60),
        "top",
        (0.45, 0.45, 0.2),
    ),
    _c(
        "sink",
        [
            "white porcelain bowl with a tap",
            "stainless steel bowl under a spout",
            "pedestal rinsing bowl",
        ],
        ["washbasin", "basin", "vanity sink", "kitchen sink", "lavatory basin", "utility sink"],
        (200, 200, 210),
        "floor",
        (0.6, 0.5, 0.9),
    ),
    _c(
        "toilet",
        ["porcelain commode", "wc with cistern", "privy"],
        ["lavatory", "loo", "water closet", "urinal", "flush toilet", "bidet"],
        (245, 245, 250),
        "floor",
        (0.4, 0.65, 0.8),
    ),
    _c(
        "towel",
        ["folded terry cloth", "hanging absorbent terrycloth", "fluffy cotton drying cloth"],
        ["bath towel", "hand towel", "washcloth", "tea towel", "beach towel", "flannel"],
        (100, 200, 200),
        "wall",
        (0.5, 0.06, 0.7),
    ),
    _c(
        "bathtub",
        [
            "long white enamel vessel for bathing",
            "clawfoot enamel trough",
            "built-in acrylic vessel with taps",
        ],
        ["bath", "tub", "jacuzzi", "hot tub", "whirlpool bath", "soaking tub"],
        (220, 230, 240),
        "floor",
        (1.7, 0.75, 0.6),
    ),
    _c(
        "shower",
        [
            "rainfall sprayer enclosure",
            "enclosed spray for bathing",
            "glass enclosure with a sprayer",
        ],
        ["shower stall", "showerhead", "walk-in shower", "shower cubicle", "wet room"],
        (170, 210, 230),
        "floor",
        (0.9, 0.9, 2.0),
    ),
    _c(
        "counter",
        ["granite prep slab by the cooker", "food preparation bench", "laminate prep bench"],
        ["countertop", "worktop", "kitchen island", "bar counter", "work surface", "benchtop"],
        (170, 170, 150),
        "floor",
        (1.8, 0.6, 0.9),
    ),
    _c(
        "fireplace",
        ["sooty firebox with logs", "stone surround with flames", "iron grate with embers"],
        ["hearth", "mantelpiece", "mantel", "wood stove", "chimney breast", "inglenook"],
        (110, 60, 50),
        "floor",
        (1.4, 0.5, 1.2),
    ),
    _c(
        "column",
        ["load-bearing pillar", "doric column", "round concrete pillar"],
        ["pilaster", "post", "support column", "colonnade", "pier"],
        (200, 190, 180),
        "floor",
        (0.4, 0.4, 2.6),
    ),
    _c(
        "railing",
        [
            "row of metal spindles",
            "waist-level wrought iron barrier",
            "polished grab rod along an edge",
        ],
        ["handrail", "banister", "balustrade", "guardrail", "railings"],
        (60, 60, 60),
        "floor",
        (2.0, 0.08, 1.0),
    ),
    _c(
        "stairs",
        ["flight of treads and risers", "ascending carpeted treads", "zigzag treads"],
        ["staircase", "stairway", "steps", "stairwell", "spiral staircase"],
        (150, 110, 80),
        "floor",
        (1.0, 2.4, 2.0),
    ),
    _c(
        "gym equipment",
        [
            "padded workout apparatus with iron plates",
            "motorised running belt",
            "steel frame with cables and pulleys",
        ],
        [
            "treadmill",
            "exercise bike",
            "rowing machine",
            "elliptical trainer",
            "dumbbells",
            "barbell",
        ],
        (80, 80, 120),
        "floor",
        (1.6, 0.8, 1.4),
    ),
    _c(
        "clothes",
        ["heap of folded garments", "shirts on hangers", "knitted woollens in a pile"],
        ["clothing", "apparel", "jacket", "trousers", "sweater", "dress"],
        (120, 60, 160),
        "top",
        (0.4, 0.3, 0.15),
    ),
    _c(
        "board panel",
        ["wipeable marker sheet", "pinned memos on a cork rectangle", "slate for chalk writing"],
        ["whiteboard", "blackboard", "noticeboard", "corkboard", "chalkboard"],
        (240, 240, 240),
        "wall",
        (1.2, 0.05, 0.9),
    ),
)

#: Labels only the taxonomy knows (absence queries of table B).
ABSENT_B: dict[str, tuple[str, ...]] = {
    "refrigerator": ("fridge", "icebox", "fridge freezer", "minibar"),
    "piano": ("grand piano", "upright piano", "keyboard instrument", "pianoforte"),
    "bicycle": ("bike", "mountain bike", "tandem", "road bike"),
    "washing machine": ("washer", "laundry machine", "tumble dryer"),
    "aquarium": ("fish tank", "terrarium", "vivarium"),
}
ABSENT_FREE_TEXT_B = (
    "a red sports car",
    "an elephant",
    "a grand piano",
    "somewhere to park a boat",
)

SUPPORTS_B = ("table", "counter", "cabinet", "shelving", "sofa", "bed", "chest of drawers")

ROOM_TYPES_B: dict[str, tuple[str, ...]] = {
    "living room": (
        "sofa",
        "table",
        "chair",
        "tv monitor",
        "picture",
        "lighting",
        "plant",
        "cushion",
        "fireplace",
        "shelving",
        "curtain",
        "column",
    ),
    "kitchen": ("counter", "cabinet", "sink", "stool", "table", "chair", "lighting", "blinds"),
    "bedroom": (
        "bed",
        "chest of drawers",
        "lighting",
        "picture",
        "curtain",
        "mirror",
        "clothes",
        "cushion",
    ),
    "bathroom": ("toilet", "sink", "bathtub", "shower", "mirror", "towel", "blinds"),
    "gym": ("gym equipment", "board panel", "mirror", "stool", "towel", "railing", "stairs"),
}
#: Wall objects that stand on the floor / hang at the top of the wall.
WALL_BOTTOM_B = ("door",)
WALL_TOP_B = ("curtain", "blinds")

#: Free-text descriptions of each label (open-vocabulary queries; ground truth = the label).
FREE_TEXT_B: dict[str, str] = {
    "chair": "something to sit on at a desk",
    "stool": "a seat without a back",
    "table": "something to put a plate on",
    "sofa": "where to lounge and watch a film",
    "bed": "somewhere to sleep",
    "chest of drawers": "where socks are kept",
    "cabinet": "where to store dishes",
    "shelving": "where books are stored",
    "plant": "something green that needs watering",
    "lighting": "something that lights up the room",
    "tv monitor": "a screen to watch the news",
    "picture": "art hanging on the wall",
    "mirror": "where I can see my reflection",
    "curtain": "fabric that covers the window",
    "sink": "where to wash my hands",
    "toilet": "where to pee",
    "towel": "something to dry myself with",
    "bathtub": "where to take a long soak",
    "shower": "where to rinse off standing up",
    "counter": "where to chop vegetables",
    "fireplace": "where to burn logs",
    "stairs": "a way to go upstairs",
    "gym equipment": "something to work out with",
    "clothes": "things to wear",
    "board panel": "something to write notes on",
}

#: Classes whose appearance names may use the label's own head word (MiniLM recognises
#: no word-free description of them; see FINDINGS.md). Every other word stays disjoint.
HEAD_WORD_ALLOWED = ("table", "stool", "window", "column")

_WORD = re.compile(r"[a-z]+")


_STOP = {"a", "an", "the", "of", "in", "on", "with", "for", "and", "to", "at", "by"}


def _words(text: str) -> set[str]:
    out = set()
    for w in _WORD.findall(text.lower()):
        if w in _STOP:
            continue
        out.add(w)
        if len(w) > 3 and w.endswith("s"):
            out.add(w[:-1])
    return out


def check_b(vocabulary: set[str] | None = None) -> list[str]:
    """Problems with table B's word and vocabulary rules (empty when it is clean)."""
    problems = []
    lang_words: set[str] = set()
    for c in CLASSES_B:
        lang_words |= _words(c.label)
        for n in c.language:
            lang_words |= _words(n)
    for label, names in ABSENT_B.items():
        lang_words |= _words(label)
        for n in names:
            lang_words |= _words(n)
    for c in CLASSES_B:
        allowed = _words(c.label) if c.label in HEAD_WORD_ALLOWED else set()
        for n in c.appearance:
            shared = (_words(n) & lang_words) - allowed
            if shared:
                problems.append(f"{c.label}: appearance {n!r} shares {sorted(shared)}")
            if vocabulary is not None and n.lower() in vocabulary:
                problems.append(f"{c.label}: appearance {n!r} is in the vocabulary")
    return problems
