"""The limits inputs are checked against before anything is allocated (see docs/safety.md).

They bound memory and time for hostile or broken files; each is far beyond what a real capture,
head model or avatar needs.
"""

MAX_IMAGE_SIDE = 16384  # px, width or height of an image or camera
MAX_IMAGE_PIXELS = 50_000_000  # px, width x height (600 MB once decoded to float32 RGB)
MIN_FOCAL_RATIO = 1e-3  # focal length / max(width, height): wider than any fisheye
MAX_FOCAL_RATIO = 1e4  # ... narrower than any telephoto lens (a 0.006 degree field of view)
MAX_PRINCIPAL_OFFSET_RATIO = 10.0  # |cx - w/2|, |cy - h/2| in units of max(width, height)
MAX_ARRAY_ELEMENTS = 256 * 1024 * 1024  # one array in an .npz, .npy member, PLY or model file
MAX_ARRAY_BYTES = 2 * 1024 ** 3  # bytes of one such array once decoded
MAX_PICKLE_BYTES = 2 * 1024 ** 3  # bytes a restricted pickle may build in total
MAX_PLY_VERTICES = 50_000_000  # Gaussians in one PLY
MAX_PARAM_FILE_BYTES = 16 * 1024 ** 2  # all arrays of one per-timestep FLAME parameter .npz
MAX_PARAM_VECTOR = 4096  # coefficients of one FLAME parameter vector (FLAME: 300 shape, 100 expression)
MAX_PICKLE_OBJECTS = 1_000_000  # objects (containers and their elements) one pickle may build, and its opcodes (FLAME: ~300)
PICKLE_OBJECTS_PER_BYTE = 16  # ... and at most this many per byte of the file (+4096): a shared container counts each time it is reached
MAX_PICKLE_DEPTH = 64  # containers inside containers in a pickle (FLAME files: 4)
MAX_SCALAR_BYTES = 4096  # one numpy scalar in a pickle (a number or a short string)
MAX_TORCH_FILE_BYTES = 16 * 1024 ** 3  # bytes of all records of one torch file once read (an avatar of 5e7 Gaussians is ~12 GB)
TORCH_BYTES_PER_FILE_BYTE = 16  # ... and at most this many per byte of the file: torch.save stores records uncompressed (1x)
MAX_TORCH_RECORDS = 100_000  # records in one torch file (ours: a few per tensor, ~100 in a checkpoint)
MAX_TORCH_PICKLE_BYTES = 64 * 1024 ** 2  # the data.pkl of one torch file (ours: a few kB; tensors live in records)
MAX_JSON_BYTES = 128 * 1024 ** 2  # one JSON file: ~120 000 frames of a split file at ~1.1 kB each (a large subject: ~50 000)
MAX_JSON_VALUES = 10_000_000  # values in one JSON file (~40 a frame: 250 000 frames), counted by separators: at most ~0.4 GB of Python objects
MIN_IMAGE_SIDE = 11  # px, width or height of an image or camera: the SSIM window of the image loss and metric (2 x 5 + 1 taps)
MAX_SETTINGS_BYTES = 1024 ** 2  # one settings file (a run's config.toml, every key written: ~8 kB)
MAX_NPZ_MEMBERS = 1024  # arrays in one .npz (a FLAME model: ~15, a parameter file: ~8); each costs ~500 bytes before it is read
MAX_VIDEO_SIDE = 8192  # px, width or height a video stream declares (8K: DCI 8192x4320, UHD 7680x4320), checked before decoding
MAX_VIDEO_PIXELS = 8192 * 4320  # px, width x height of one video frame (8K)
