/// @file test_fuzz_corpus.cpp
/// @brief Hostile bitstreams (issue #9): every committed fuzz input (fuzz/corpus, fuzz/crashes)
/// replayed through the fuzzers' own harness, the seed generator, and hostile inputs behind valid
/// CRCs that the fuzzers reach only through re-sealing: absurd counts in small files, future
/// versions, each section's payload corrupted, missing sections.
#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <map>
#include <tuple>

#include <yaml-cpp/yaml.h>

#include "../../fuzz/fuzz_harness.h"
#include "../../fuzz/fuzz_seeds.h"
#include "crpgs/atomic_file.h"
#include "crpgs/codec.h"
#include "crpgs/coding/bitstream.h"
#include "test_registry.h"

namespace crpgs {
namespace {

namespace fs = std::filesystem;
using coding::Bytes;

std::string plugins_missing() {
  const auto& r = test::test_registry();
  for (auto [kind, type] :
       {std::pair{CRPGS_KIND_CONTEXT, "hash_grid"}, std::pair{CRPGS_KIND_ENTROPY, "gaussian"},
        std::pair{CRPGS_KIND_FEATURES, "sfa"}})
    if (!r.find(kind, type))
      return std::string("the ") + type + " plugin is not built in " + CRPGS_PLUGIN_BUILD_DIR;
  return "";
}

#define SKIP_WITHOUT_PLUGINS()                 \
  do {                                         \
    const std::string why = plugins_missing(); \
    if (!why.empty()) GTEST_SKIP() << why;     \
  } while (0)

const std::map<std::string, Bytes>& seeds() {
  static const std::map<std::string, Bytes> s = [] {
    std::map<std::string, Bytes> out;
    auto made = fuzz::make_seeds(test::test_registry());
    if (!made.ok()) throw StatusError(made.status());
    for (auto& seed : *made) out[seed.name] = std::move(seed.bytes);
    return out;
  }();
  return s;
}

fuzz::Outcome decode(const Bytes& b) {
  return fuzz::run_one(b.data(), b.size(), /*sealed=*/false, test::test_registry());
}

/// The file rebuilt (valid CRCs) with `edit` applied to every section; an edit returning false
/// drops the section.
Bytes rebuild(const Bytes& file, const std::function<bool(coding::Section&)>& edit) {
  auto ct = coding::ContainerReader::parse(file);
  if (!ct.ok()) throw StatusError(ct.status());
  coding::ContainerWriter w(ct->header.config_hash, ct->header.flags);
  for (coding::Section s : ct->sections) {
    if (!edit(s)) continue;
    const Status st = w.add_section(std::move(s));
    if (!st.ok()) throw StatusError(st);
  }
  return w.finish();
}

Bytes with_payload(const Bytes& file, const std::string& id, const Bytes& payload) {
  return rebuild(file, [&](coding::Section& s) {
    if (s.id == id) s.payload = payload;
    return true;
  });
}

std::vector<coding::Section> sections_of(const Bytes& file) {
  auto ct = coding::ContainerReader::parse(file);
  if (!ct.ok()) throw StatusError(ct.status());
  return std::move(ct).value().sections;
}

Bytes payload_of(const Bytes& file, const std::string& id) {
  auto ct = coding::ContainerReader::parse(file);
  if (!ct.ok()) throw StatusError(ct.status());
  const coding::Section* s = ct->find(id);
  if (!s) throw std::runtime_error("no section " + id);
  return s->payload;
}

void expect_refused(const fuzz::Outcome& o, const std::string& mentions, const std::string& what) {
  EXPECT_FALSE(o.decoded) << what;
  EXPECT_FALSE(o.message.empty()) << what;
  EXPECT_NE(o.message.find(mentions), std::string::npos)
      << what << ": the message should mention '" << mentions << "': " << o.message;
}

// --- The corpus -------------------------------------------------------------------------------

TEST(FuzzCorpus, SeedsDecodeAndResealLeavesThemUnchanged) {
  SKIP_WITHOUT_PLUGINS();
  ASSERT_GE(seeds().size(), 7u);
  for (const auto& [name, bytes] : seeds()) {
    EXPECT_LT(bytes.size(), 16u * 1024) << name << " should stay small";
    const fuzz::Outcome o = decode(bytes);
    EXPECT_TRUE(o.decoded) << name << ": " << o.message;
    EXPECT_EQ(fuzz::reseal(bytes.data(), bytes.size()), bytes) << name;
  }
}

TEST(FuzzCorpus, ResealRepairsEveryChecksum) {
  SKIP_WITHOUT_PLUGINS();
  const Bytes& good = seeds().at("seed-plain.crpgs");
  Bytes bad = good;
  bad[24] ^= 1;  // header CRC
  for (const auto& s : sections_of(good))
    bad[size_t(s.file_offset) + 4 + 1 + s.component_id.size() + 12] ^= 0x80;  // each section CRC
  EXPECT_FALSE(decode(bad).decoded);
  EXPECT_EQ(fuzz::reseal(bad.data(), bad.size()), good);
}

/// Every file of fuzz/corpus/<target> and fuzz/crashes/<target>, decoded as that target does:
/// decoded, or refused with a message (a crash, hang or sanitizer report fails the test run).
TEST(FuzzCorpus, CommittedCorpusAndCrashesAreDecodedOrRefused) {
  SKIP_WITHOUT_PLUGINS();
  const fs::path root = fs::path(CRPGS_SOURCE_DIR) / "fuzz";
  size_t files = 0, decoded = 0;
  for (const char* kind : {"corpus", "crashes"})
    for (const char* target : {"decode", "decode_sealed"}) {
      const fs::path dir = root / kind / target;
      if (!fs::is_directory(dir)) continue;
      for (const auto& e : fs::directory_iterator(dir)) {
        if (!e.is_regular_file() || e.path().filename().string()[0] == '.') continue;
        auto bytes = read_file_bytes(e.path().string());
        ASSERT_TRUE(bytes.ok()) << bytes.status().to_string();
        const fuzz::Outcome o =
            fuzz::run_one(bytes->data(), bytes->size(), std::string(target) == "decode_sealed",
                          test::test_registry());
        EXPECT_TRUE(o.decoded || !o.message.empty()) << e.path();
        ++files;
        decoded += o.decoded;
      }
    }
  EXPECT_GE(files, 14u) << "the committed corpus (at least the seeds) is missing from " << root;
  EXPECT_GT(decoded, 0u) << "no committed input decodes: the corpus has lost its valid seeds";
}

// --- Older formats -----------------------------------------------------------------------------

/// tests/data/format_1_1 holds the seeds as format 1.1 wrote them (its README says how). They
/// decode as written (1 + tanh steps) to the models the committed format 1.2 seeds
/// (fuzz/corpus/decode, the same symbols) decode to. seed-small_steps fails to decode if its
/// steps are computed the 1.2 way. Committed files on both sides: the symbols of a regenerated
/// seed come from torch::randn, whose last bits depend on the CPU's vector unit.
TEST(OlderFormats, FormatOneOneSeedsDecodeAsWritten) {
  SKIP_WITHOUT_PLUGINS();
  const fs::path dir = fs::path(CRPGS_SOURCE_DIR) / "tests" / "data" / "format_1_1";
  const fs::path current = fs::path(CRPGS_SOURCE_DIR) / "fuzz" / "corpus" / "decode";
  const ComponentRegistry& registry = test::test_registry();
  size_t checked = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (e.path().extension() != ".crpgs") continue;
    auto old_bytes = read_file_bytes(e.path().string());
    ASSERT_TRUE(old_bytes.ok()) << old_bytes.status().to_string();
    auto new_bytes = read_file_bytes((current / name).string());
    ASSERT_TRUE(new_bytes.ok()) << name
                                << " has no format 1.2 twin: " << new_bytes.status().to_string();
    for (const auto& s : sections_of(*old_bytes)) {
      if (s.component_id == "org.crpgs.codec.anchor_model") {
        EXPECT_EQ(s.component_minor, 1) << name << " " << s.id;
      }
    }
    auto old_dec = decode_model(*old_bytes, registry);
    ASSERT_TRUE(old_dec.ok()) << name << ": " << old_dec.status().to_string();
    auto new_dec = decode_model(*new_bytes, registry);
    ASSERT_TRUE(new_dec.ok()) << name << ": " << new_dec.status().to_string();
    const CodedModel &a = old_dec->model, &b = new_dec->model;
    EXPECT_EQ(a.steps, StepForm::kOnePlusTanh) << name;
    EXPECT_EQ(b.steps, StepForm::kTwoSigmoid) << name;
    for (const auto& [what, x, y] : {std::tuple{"voxels", a.voxels, b.voxels},
                                     std::tuple{"offset masks", a.offset_masks, b.offset_masks},
                                     std::tuple{"feature symbols", a.feature_sym, b.feature_sym},
                                     std::tuple{"scaling symbols", a.scaling_sym, b.scaling_sym},
                                     std::tuple{"offset symbols", a.offset_sym, b.offset_sym}})
      EXPECT_TRUE(torch::equal(x, y)) << name << ": " << what;
    EXPECT_EQ(a.links.defined(), b.links.defined()) << name;
    if (a.links.defined() && b.links.defined()) {
      EXPECT_TRUE(torch::equal(a.links, b.links)) << name;
    }
    // The same steps, up to 1 + tanh's rounding near 1 (an ulp of 1, times Q0): in
    // seed-small_steps (a ≈ −5) that is ~1e-3 of the step, and enough to change every CDF.
    const int64_t dc = a.feature_sym.size(1);
    const auto pa = coded_entropy_params(a, *old_dec->components.context, dc);
    const auto pb = coded_entropy_params(b, *new_dec->components.context, dc);
    for (const auto& [x, y, q0] :
         {std::tuple{pa.q_f, pb.q_f, a.q0.feature}, std::tuple{pa.q_s, pb.q_s, a.q0.scaling},
          std::tuple{pa.q_o, pb.q_o, a.q0.offset}})
      EXPECT_TRUE(((x - y).abs() <= 1e-5 * y + 1.2e-7 * q0).all().item<bool>()) << name;
    if (name == "seed-small_steps.crpgs") {  // still the case it was made for
      EXPECT_LT(pb.q_f.max().item<double>(), 1e-3 * a.q0.feature);
    }
    ++checked;
  }
  EXPECT_GE(checked, 9u) << "the format 1.1 files are missing from " << dir;
}

// --- Absurd counts in small files --------------------------------------------------------------

TEST(HostileBitstream, HeadClaimingHugeCountsIsRefused) {
  SKIP_WITHOUT_PLUGINS();
  const Bytes& good = seeds().at("seed-plain.crpgs");
  const Bytes head = payload_of(good, "HEAD");
  coding::ByteReader r(head);
  uint64_t v[4];
  for (auto& x : v) ASSERT_TRUE(r.read_varint(&x).ok());
  const Bytes rest(head.end() - long(r.remaining()), head.end());
  const uint64_t huge[] = {uint64_t(1) << 32, uint64_t(1) << 40,
                           std::numeric_limits<uint64_t>::max()};
  const char* names[4] = {"anchors", "offsets", "feature width", "chunk"};
  for (int field = 0; field < 4; ++field)
    for (uint64_t h : huge) {
      coding::ByteWriter w;
      for (int i = 0; i < 4; ++i) w.put_varint(i == field ? h : v[i]);
      w.put_bytes(rest);
      const Bytes file = with_payload(good, "HEAD", w.take());
      EXPECT_LT(file.size(), good.size() + 64);
      // N is checked against the decoded geometry, the others against limits, before any use.
      expect_refused(decode(file), field == 0 ? "HEAD claims" : "HEAD",
                     std::string(names[field]) + " = " + std::to_string(h));
    }
}

TEST(HostileBitstream, AnchorMaskClaiming2To32AnchorsInOneKilobyteIsRefused) {
  SKIP_WITHOUT_PLUGINS();
  const Bytes& good = seeds().at("seed-links_paper.crpgs");
  const uint64_t n0 = uint64_t(1) << 32;
  coding::ByteWriter w;
  w.put_varint(n0);  // AMSK: model anchor count
  w.put_varint(n0);  // the Bernoulli stream agrees
  w.put_u32(1);      // p(1) = 2^-16: the cheapest possible zeros
  w.put_u64(uint64_t(1) << 40);
  while (w.size() < 1024) w.put_u32(0);
  const fuzz::Outcome o = decode(with_payload(good, "AMSK", w.take()));
  // Refused by the count-versus-bytes check that precedes the allocation of n0 bytes.
  expect_refused(o, "AMSK", "AMSK n0 = 2^32");
  EXPECT_NE(o.message.find("code at most"), std::string::npos) << o.message;
}

TEST(HostileBitstream, MlpTensorLargerThanItsSectionIsRefused) {
  SKIP_WITHOUT_PLUGINS();
  const Bytes& good = seeds().at("seed-plain.crpgs");
  coding::ByteWriter w;
  w.put_varint(1);
  w.put_string("mlp_opacity.w1");
  w.put_varint(2);
  w.put_varint(uint64_t(1) << 20);
  w.put_varint(uint64_t(1) << 20);
  while (w.size() < 1024) w.put_u8(0);
  expect_refused(decode(with_payload(good, "MLPS", w.take())), "MLPS", "a 2^40-element tensor");
}

TEST(HostileBitstream, ConfigAskingForAHugeGridIsRefusedBeforeAllocating) {
  SKIP_WITHOUT_PLUGINS();
  for (const char* seed : {"seed-plain.crpgs", "seed-sfa.crpgs"}) {
    const Bytes& good = seeds().at(seed);
    const Bytes conf = payload_of(good, "CONF");
    YAML::Node root = YAML::Load(std::string(conf.begin(), conf.end()));
    const char* block = std::string(seed) == "seed-sfa.crpgs" ? "features" : "context";
    // Levels of 2^30 entries (fine resolutions fill them): tens of GiB of floats.
    root[block]["log2_hashmap_size"] = 30;
    root[block]["resolutions"] = std::vector<int>(root[block]["resolutions"].size(), 4096);
    YAML::Emitter e;
    e << root;
    const std::string text = e.c_str();
    expect_refused(decode(with_payload(good, "CONF", Bytes(text.begin(), text.end()))), "limit",
                   std::string(seed) + " with 2^30-entry " + block + " grid levels");
  }
}

// --- Versions ----------------------------------------------------------------------------------

TEST(HostileBitstream, FutureVersionsAreRefusedAndFutureMinorsRead) {
  SKIP_WITHOUT_PLUGINS();
  const Bytes& good = seeds().at("seed-plain.crpgs");
  auto patched = [&](size_t at, uint16_t v) {
    Bytes b = good;
    b[at] = uint8_t(v);
    b[at + 1] = uint8_t(v >> 8);
    return fuzz::reseal(b.data(), b.size());
  };
  // Container: a future minor is read (new fields are gated on it), a future major is not.
  EXPECT_TRUE(decode(patched(6, coding::kContainerMinorVersion + 1)).decoded);
  auto major = decode_model(patched(4, coding::kContainerMajorVersion + 1), test::test_registry());
  ASSERT_FALSE(major.ok());
  EXPECT_EQ(major.status().code(), StatusCode::kUnsupportedVersion);
  EXPECT_NE(major.status().message().find("version"), std::string::npos);
  // Sections: the same rule, named by section.
  for (const auto& s : sections_of(good)) {
    for (uint16_t minor_bump : {0, 1}) {
      const Bytes file = rebuild(good, [&](coding::Section& t) {
        if (t.id == s.id) {
          if (minor_bump)
            ++t.component_minor;
          else
            ++t.component_major;
        }
        return true;
      });
      auto dec = decode_model(file, test::test_registry());
      if (minor_bump && s.component_id == "org.crpgs.codec.anchor_model") {
        // This codec's minors can change its arithmetic (1.2 did): refused, not misread.
        ASSERT_FALSE(dec.ok()) << s.id << " minor + 1";
        EXPECT_EQ(dec.status().code(), StatusCode::kUnsupportedVersion) << s.id;
        EXPECT_NE(dec.status().message().find("newer crpgs"), std::string::npos)
            << dec.status().message();
      } else if (minor_bump) {
        EXPECT_TRUE(dec.ok()) << s.id << " minor + 1: " << dec.status().to_string();
      } else {
        ASSERT_FALSE(dec.ok()) << s.id << " major + 1";
        EXPECT_EQ(dec.status().code(), StatusCode::kUnsupportedVersion) << s.id;
        EXPECT_NE(dec.status().message().find(s.id), std::string::npos) << dec.status().message();
      }
    }
  }
  // Versions inside payloads: the grid state's, the gaussian stream's table format, GEOM's format.
  Bytes ctxs = payload_of(good, "CTXS");
  ctxs[4] = uint8_t(ctxs[4] + 1);
  expect_refused(decode(with_payload(good, "CTXS", ctxs)), "version", "grid state version + 1");
  Bytes feat = payload_of(good, "FEAT");
  coding::ByteReader fr(feat);
  uint64_t len = 0;
  ASSERT_TRUE(fr.read_varint(&len).ok());
  feat[fr.position()] = uint8_t(feat[fr.position()] + 1);
  expect_refused(decode(with_payload(good, "FEAT", feat)), "version", "gaussian format + 1");
  Bytes geom = payload_of(good, "GEOM");
  geom[0] = uint8_t(geom[0] + 1);
  expect_refused(decode(with_payload(good, "GEOM", geom)), "GEOM", "geometry format + 1");
}

// --- Every section of every seed, corrupted behind a valid CRC ----------------------------------

TEST(HostileBitstream, EachSectionPayloadCorruptedBehindAValidCrcIsRefusedOrDecoded) {
  SKIP_WITHOUT_PLUGINS();
  size_t cases = 0;
  for (const auto& [name, good] : seeds()) {
    for (const auto& s : sections_of(good)) {
      const Bytes& p = s.payload;
      const std::string where = name + " " + s.id;
      // Shortened or lengthened payloads: refused, except CONF, whose YAML may still parse.
      std::vector<std::pair<std::string, Bytes>> resized = {
          {"emptied", {}},
          {"halved", Bytes(p.begin(), p.begin() + long(p.size() / 2))},
          {"one byte short", Bytes(p.begin(), p.end() - (p.empty() ? 0 : 1))}};
      resized.push_back({"one byte longer", p});
      resized.back().second.push_back(0x5a);
      for (const auto& [how, payload] : resized) {
        if (payload == p) continue;
        const fuzz::Outcome o = decode(with_payload(good, s.id, payload));
        ++cases;
        if (s.id == "CONF") {
          EXPECT_TRUE(o.decoded || !o.message.empty()) << where << " " << how;
        } else {
          EXPECT_FALSE(o.decoded) << where << " " << how;
          EXPECT_FALSE(o.message.empty()) << where << " " << how;
        }
      }
      // Flipped bits and overwritten bytes anywhere in the payload: decoded or refused.
      for (size_t k = 0; k < 8 && !p.empty(); ++k) {
        Bytes q = p;
        const size_t at = (k * 7919 + 13) % q.size();
        if (k % 3 == 2)
          q[at] = 0xff;
        else
          q[at] ^= uint8_t(1u << (k % 8));
        const fuzz::Outcome o = decode(with_payload(good, s.id, q));
        ++cases;
        EXPECT_TRUE(o.decoded || !o.message.empty()) << where << " byte " << at;
      }
    }
  }
  EXPECT_GT(cases, 300u);
}

TEST(HostileBitstream, MissingSectionsAreRefusedByName) {
  SKIP_WITHOUT_PLUGINS();
  for (const char* seed : {"seed-links.crpgs", "seed-links_paper.crpgs", "seed-sfa.crpgs"}) {
    const Bytes& good = seeds().at(seed);
    for (const auto& s : sections_of(good)) {
      const Bytes file = rebuild(good, [&](coding::Section& t) { return t.id != s.id; });
      expect_refused(decode(file), s.id, std::string(seed) + " without " + s.id);
    }
  }
}

}  // namespace
}  // namespace crpgs
