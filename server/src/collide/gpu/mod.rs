//! wgpu compute backends of the collision stage (the paper's all-pairs kernel and
//! a BVH traversal kernel).
