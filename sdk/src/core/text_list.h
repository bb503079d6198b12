/// @file text_list.h
/// @brief Lists of names in messages: "a, b, c", and the nearest valid name to a misspelt one;
/// numbers as %g writes them.
#pragma once

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

namespace crpgs {

/// A number as printf's %g writes it ("0.001", "1.5", "1e-05").
inline std::string g_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

inline std::string join(const std::vector<std::string>& items, const char* sep = ", ") {
  std::string out;
  for (size_t i = 0; i < items.size(); ++i) out += (i ? sep : "") + items[i];
  return out;
}

/// The items of a list `join` wrote with `sep`; none for "".
inline std::vector<std::string> split(const std::string& text, const std::string& sep = ", ") {
  std::vector<std::string> out;
  for (size_t begin = 0; !text.empty();) {
    const size_t end = text.find(sep, begin);
    out.push_back(text.substr(begin, end - begin));
    if (end == std::string::npos) break;
    begin = end + sep.size();
  }
  return out;
}

/// Edits (insert, delete, substitute, swap two neighbours) that turn `a` into `b`.
inline size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::vector<size_t>> d(a.size() + 1, std::vector<size_t>(b.size() + 1));
  for (size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (size_t i = 1; i <= a.size(); ++i)
    for (size_t j = 1; j <= b.size(); ++j) {
      d[i][j] = std::min(
          {d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  return d[a.size()][b.size()];
}

/// ", did you mean 'lambda'?" for the one candidate nearest to `word` when it is a plausible
/// typo (at most a third of the word's letters off, at least one allowed); "" when none is, or
/// when two are equally near (a guess between them would mislead).
inline std::string did_you_mean(const std::string& word, const std::vector<std::string>& names) {
  const size_t limit = std::max<size_t>(1, word.size() / 3);
  size_t best = limit + 1;
  const std::string* pick = nullptr;
  bool tie = false;
  for (const std::string& n : names) {
    const size_t d = edit_distance(word, n);
    if (d < best) {
      best = d;
      pick = &n;
      tie = false;
    } else if (d == best && pick && n != *pick) {
      tie = true;
    }
  }
  return pick && !tie ? ", did you mean '" + *pick + "'?" : "";
}

}  // namespace crpgs
