//! Samplings of the hemisphere. (Skeleton.)
