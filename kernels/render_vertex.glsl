#version 330 core
// Offscreen mesh renderer (rigslim.render): world-space positions, normals and
// per-vertex colours; clip position = u_mvp [x; 1]. The numpy reference is
// rigslim.render.render_numpy.
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec3 a_color;

uniform mat4 u_mvp;

out vec3 v_normal;
out vec3 v_color;

void main() {
    gl_Position = u_mvp * vec4(a_position, 1.0);
    v_normal = a_normal;
    v_color = a_color;
}
