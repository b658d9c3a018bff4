"""Point-cloud operations shared by the env's observations, the policies' data and
Contact-GraspNet: ``pointops`` (farthest-point sampling, ball query, kNN interpolation in
batched torch, CPU or CUDA) and its Triton kernel for farthest-point sampling on CUDA
(``fps_triton``)."""
