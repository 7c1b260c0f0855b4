#pragma once

namespace rekon {

// `rekon run --dataset DIR --out DIR [--config FILE] [--set key=value ...]`
int runMain(int argc, char** argv);
// `rekon demo [--out DIR]`: the whole pipeline on the built-in default scene.
int demoMain(int argc, char** argv);

}  // namespace rekon
