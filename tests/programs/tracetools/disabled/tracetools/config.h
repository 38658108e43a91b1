// The `disabled` variant of the vendored tracetools config.h (see ../../README.md): what configure_file makes of
// ros2/ros2_tracing's config.h.in (Jazzy, 73a7e6db) when the package is built with -DTRACETOOLS_DISABLED=ON, which
// also forces TRACETOOLS_TRACEPOINTS_EXCLUDED.  It is put first on the include path, before ../jazzy, whose
// tracetools.h then compiles every tracepoint out.
//
// Copyright 2019 Robert Bosch GmbH
//
// Licensed under the Apache License, Version 2.0 (the "License");
// you may not use this file except in compliance with the License.
// You may obtain a copy of the License at
//
//     http://www.apache.org/licenses/LICENSE-2.0
//
// Unless required by applicable law or agreed to in writing, software
// distributed under the License is distributed on an "AS IS" BASIS,
// WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
// See the License for the specific language governing permissions and
// limitations under the License.

#ifndef TRACETOOLS__CONFIG_H_
#define TRACETOOLS__CONFIG_H_

#define TRACETOOLS_DISABLED
#define TRACETOOLS_TRACEPOINTS_EXCLUDED

#endif  // TRACETOOLS__CONFIG_H_
