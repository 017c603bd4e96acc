//! Gonioreflectometer kinematics. (Skeleton.)
