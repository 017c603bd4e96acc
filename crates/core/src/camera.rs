//! Pinhole camera with lens distortion. (Skeleton.)
