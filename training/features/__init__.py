"""Python access to the engine's audio features (the C++ `dance-features` CLI is the only implementation)."""
