"""What runs around a fill, never a fill itself.

Before: :mod:`.outliers` (swapped and ghost markers become gaps).  Around: :mod:`.windows` (a long take filled in
overlapping windows).  After: :mod:`.plausibility` (a filled run kept inside the body and its speeds) and
:mod:`.smooth` (Savitzky-Golay smoothing on request).
"""
