/* @file plugin_abi.h
 * @brief The C boundary between the host and a plugin shared library.
 *
 * A plugin exports exactly one symbol, `crpgs_plugin_v1`, returning a pointer to a static
 * descriptor. No exception crosses this boundary: create() reports failure through its return
 * code and the message buffer. The object returned by create() is a pointer to the C++ interface
 * of the descriptor's kind (crpgs::EntropyModel, crpgs::ContextModel, crpgs::FeatureModel,
 * crpgs::Rasterizer), which is why build_info must match the host exactly.
 */
#ifndef CRPGS_PLUGIN_ABI_H
#define CRPGS_PLUGIN_ABI_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define CRPGS_PLUGIN_ENTRY_SYMBOL "crpgs_plugin_v1"

typedef enum crpgs_kind {
  CRPGS_KIND_ENTROPY = 1,
  CRPGS_KIND_CONTEXT = 2,
  CRPGS_KIND_FEATURES = 3,
  CRPGS_KIND_RASTERIZER = 4
} crpgs_kind;

typedef struct crpgs_build_info {
  const char* compiler;      /* e.g. "GCC 12.2.0" */
  const char* torch_version; /* e.g. "1.13.0" */
  const char* cxx_abi;       /* "cxx11" or "old" (_GLIBCXX_USE_CXX11_ABI) */
  int32_t cuda;              /* 1 if built with CUDA kernels */
} crpgs_build_info;

/* Host-provided facts a component needs to size itself. */
typedef struct crpgs_create_args {
  int32_t feature_dim; /* width of the anchor feature seen by the MLPs (D_0 = 50 in HAC) */
  int32_t n_offsets;   /* neural Gaussians per anchor (K = 10) */
  int32_t device_cuda; /* 1: tensors live on the CUDA device */
  int32_t coded_dim;   /* width of the entropy-coded per-anchor feature (D_i; = feature_dim
                          without SFA); 0 means feature_dim */
  int32_t reserved[4];
} crpgs_create_args;

/* Return codes of create(). */
#define CRPGS_PLUGIN_OK 0
#define CRPGS_PLUGIN_ERROR 1

typedef struct crpgs_plugin_descriptor {
  uint32_t abi_version;  /* CRPGS_PLUGIN_ABI_VERSION the plugin was built against */
  uint32_t kind;         /* crpgs_kind */
  const char* id;        /* reverse-DNS identifier, e.g. "org.crpgs.context.hash_grid" */
  const char* type_name; /* the YAML `type:` value */
  uint32_t version_major, version_minor;
  crpgs_build_info build;
  const char* schema_yaml; /* YAML list of {key, type, default, min, max, choices, doc} */
  /* config_yaml: the resolved, schema-checked config block as YAML text. On failure returns
   * CRPGS_PLUGIN_ERROR and writes a NUL-terminated message into err (at most err_len bytes). */
  int (*create)(const char* config_yaml, const crpgs_create_args* args, void** out_object,
                char* err, size_t err_len);
  void (*destroy)(void* object);
} crpgs_plugin_descriptor;

typedef const crpgs_plugin_descriptor* (*crpgs_plugin_entry_fn)(void);

#ifdef __cplusplus
}
#endif

#endif /* CRPGS_PLUGIN_ABI_H */
