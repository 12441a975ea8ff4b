"""Readers and writers: markers (C3D, TRC, NPZ), body motion (ASF/AMC, BVH), skinned glTF,
and the seeded synthetic face (the embedded default data)."""

# --- markers + synthetic face (issue 2) ---
# --- end markers ---

# --- motion (issue 5) ---
# --- end motion ---

# --- glTF (issue 6) ---
# --- end glTF ---
