# Sources of sdk/src/train (paths relative to sdk/).
list(APPEND CRPGS_BASE_SOURCES
  src/train/sections.cpp
  src/train/shared_prefix.cpp)     # which runs share the start of their training
list(APPEND CRPGS_TORCH_SOURCES
  src/train/trainer.cpp            # loop, checkpoints, evaluation, setup from a config
  src/train/pipeline.cpp           # what front ends drive: configs, model sources, bitstreams
  src/train/ssim.cpp               # the SSIM loss with its own backward
  src/train/lpips.cpp              # LPIPS from a user's TorchScript module (eval)
  src/train/scene_generator.cpp)   # the embedded synthetic scene
