"""Chunk type codes and channel layouts shared by the encoder and the decoder (GSZ.md §4)."""

CHUNK_GEOM = b"GEOM"   # octree geometry (required)
CHUNK_ATTR = b"ATTR"   # RAHT + direct quantised attributes (required)
CHUNK_SHVQ = b"SHVQ"   # higher-degree SH: codebook, kept vectors, indices (required when degree > 0)
CHUNK_META = b"META"   # zstd-compressed UTF-8 JSON, informative only (optional)
CHUNK_TILE = b"TILE"   # tile table: per spatial tile its bounding box and Gaussian count (1.2)
CHUNK_SHCL = b"SHCL"   # importance classes of a part's kept SH vectors: their coding order (1.3)
CHUNK_RWGT = b"RWGT"   # importance classes and weights of a part's RAHT leaves (1.5)
CHUNK_SHXF = b"SHXF"   # the colour space of a part's SH vectors (1.6) and DC colour (1.7): luma/chroma
CHUNK_SHRF = b"SHRF"   # a part's kept SH vectors as residuals of a codeword each: their indices (1.9)
KNOWN_CHUNKS = (CHUNK_GEOM, CHUNK_ATTR, CHUNK_SHVQ, CHUNK_META, CHUNK_TILE, CHUNK_SHCL, CHUNK_RWGT,
                CHUNK_SHXF, CHUNK_SHRF)

#: Channels that go through RAHT, in stream order.
RAHT_CHANNELS = ("opacity", "roll", "pitch", "yaw", "f_dc_0", "f_dc_1", "f_dc_2")
#: Channels quantised directly in Morton point order.
DIRECT_CHANNELS = ("scale_0", "scale_1", "scale_2")
#: Rotation parameterisation codes (ATTR byte 0).
ROTATION_EULER_ZYX = 0
